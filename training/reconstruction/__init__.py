"""Shape from spectrum: the complete body rebuilt from a union's spectrum."""
