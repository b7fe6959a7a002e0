"""What is measured on a rebuilt body, by the service and by the decoder's evaluation alike."""

import numpy as np

from app.contract import BOUNDARY_RATIO

UP_AXIS = 2  # the template's up axis (z): anny's rest pose stands along it


def body_height(vertices: np.ndarray) -> float:
    """A body's extent along the template's up axis, in its units (metres)."""
    return float(np.ptp(vertices[:, UP_AXIS]))


def surface_area(vertices: np.ndarray, faces: np.ndarray) -> float:
    """Total triangle area (m² for vertices in metres)."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    return float(np.linalg.norm(np.cross(b - a, c - a), axis=1).sum() / 2)


def spectrum_gap(body: np.ndarray, target: np.ndarray) -> float:
    """Mean relative difference of λ₂…λ_k between a rebuilt body's spectrum and the spectrum it
    was decoded from: λ₁ of a closed body is 0, where a relative difference means nothing."""
    return float(np.mean(np.abs(body[1:] - target[1:]) / np.maximum(np.abs(target[1:]), 1e-12)))


def open_surface(eigenvalues: np.ndarray) -> np.ndarray:
    """Whether spectra (..., k) are an open surface's (λ₁ > ``BOUNDARY_RATIO`` · λ₂: a boundary, such
    as a scan's holes), not a closed body's (λ₁ = 0 up to the solver): the decoder graph's router's rule."""
    return eigenvalues[..., 0] > BOUNDARY_RATIO * eigenvalues[..., 1]
