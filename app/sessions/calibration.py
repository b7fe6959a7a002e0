"""σ of a session's union solved on its fused views: how far such unions fall from the exact one,
as a share of each eigenvalue, by how many views a session has.

A fused union is a point cloud's spectrum, not a prediction, but its boundary is inferred
(where views stop and no other goes on) and its error grows with the views' count as a session
closes around the body. ``spectral-unions-train calibrate-sessions`` measures it on anny
sessions with exact truth and writes :data:`~app.contract.SESSIONS_FILE`: per band of view
counts and per eigenvalue, the relative σ with which union ± INTERVAL_Z·σ holds 90 % of the
calibration sessions' eigenvalues, and how often it held on held-out people.
"""

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np


@dataclass(frozen=True)
class FusedCalibration:
    """Relative σ per band: ``up_to[i]`` views at most use ``relative[i]`` (k,)."""

    up_to: tuple[int, ...]
    relative: np.ndarray

    @classmethod
    def load(cls, path: Path, k: int) -> "FusedCalibration":
        content = json.loads(path.read_text())
        bands = content["bands"]
        relative = np.array([band["relative_sigma"] for band in bands], dtype=np.float64)
        if relative.shape != (len(bands), k) or not np.all(np.isfinite(relative)) or np.any(relative < 0):
            raise ValueError(f"{path.name}: relative_sigma must be {len(bands)} rows of {k} finite values ≥ 0")
        up_to = tuple(int(band["views_up_to"]) for band in bands)
        if list(up_to) != sorted(set(up_to)):
            raise ValueError(f"{path.name}: bands must rise in views_up_to")
        return cls(up_to, relative)

    def sigma(self, eigenvalues: np.ndarray, views: int) -> np.ndarray:
        """σ (1/m²) of a union of ``views`` fused views: its band's (the last band's beyond)."""
        band = min(int(np.searchsorted(self.up_to, views)), len(self.up_to) - 1)
        return self.relative[band] * np.asarray(eigenvalues, dtype=np.float64)
