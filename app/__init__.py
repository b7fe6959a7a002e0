"""spectral-unions: Laplace–Beltrami spectra of partial deformable shapes, served over HTTP."""

__version__ = "0.2.0"
