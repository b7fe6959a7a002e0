"""Checks on spectra that clients send: the operator is only defined on real spectra.

A spectrum here is the first k eigenvalues of a shape in 1/m², ascending and non-negative. A
vector that is none of these (NaN, negative, decreasing, wrong length) is the client's error,
reported as such instead of producing a confident-looking union of garbage.
"""

import numpy as np

from app.core.errors import InputError
from app.geometry.spectrum import MAX_EIGENVALUE, ORDER_TOLERANCE


class InvalidSpectrum(InputError):
    """A spectrum in a request is not a valid truncated spectrum."""

    slug = "invalid-spectrum"
    title = "Invalid spectrum"


def checked_spectrum(values: list[float] | np.ndarray, k: int, name: str = "spectrum") -> np.ndarray:
    """The values as a float64 (k,) array, or :class:`InvalidSpectrum` saying what is wrong."""
    spectrum = np.asarray(values, dtype=np.float64)
    if spectrum.shape != (k,):
        raise InvalidSpectrum(f"{name} must hold exactly {k} eigenvalues, got {spectrum.size}")
    if not np.isfinite(spectrum).all():
        raise InvalidSpectrum(f"{name} holds NaN or infinite values")
    if spectrum.max() > MAX_EIGENVALUE:
        raise InvalidSpectrum(
            f"{name} holds {spectrum.max():.3g}; eigenvalues above {MAX_EIGENVALUE:g} 1/m² are no scan's "
            "and past what the models represent"
        )
    scale = max(float(np.abs(spectrum).max()), 1.0)
    if spectrum.min() < -ORDER_TOLERANCE * scale:
        raise InvalidSpectrum(f"{name} has negative eigenvalues: Laplace–Beltrami spectra are ≥ 0")
    if np.any(np.diff(spectrum) < -ORDER_TOLERANCE * scale):
        raise InvalidSpectrum(f"{name} is not in ascending order")
    return np.clip(spectrum, 0, None)
