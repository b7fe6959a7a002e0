"""Identity retrieval: a ShapeDNA database of complete shapes, queried by spectrum."""
