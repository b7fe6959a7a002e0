"""HTTP layer: thin routes over the geometry and inference modules."""
