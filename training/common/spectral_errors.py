"""How far predicted spectra lie from the true ones: the figures every table and the training's
epoch selection read, defined once."""

import numpy as np


def spectral_errors(predicted: np.ndarray, truth: np.ndarray) -> dict:
    """mse and mae over all eigenvalues (1/m²), and mean relative error, overall and per index.

    A closed union has λ₁ = 0, where a relative error means nothing: such entries are left out.
    """
    difference = predicted - truth
    meaningful = truth > 1e-6
    relative = np.where(meaningful, np.abs(difference) / np.where(meaningful, truth, 1), 0.0)
    per_index = relative.sum(0) / np.maximum(meaningful.sum(0), 1)
    return {
        "mse": float(np.mean(difference**2)),
        "mae": float(np.mean(np.abs(difference))),
        "mre": float(relative.sum() / max(meaningful.sum(), 1)),
        "mre_per_eigenvalue": [round(float(x), 5) for x in per_index],
    }
