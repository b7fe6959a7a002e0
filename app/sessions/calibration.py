"""σ of a session's union solved on its views, and which way an unregistered session is read.

A union solved on the views (fused: registered views; aligned: views brought into one frame
through their places) is a spectrum solved on the views, not a prediction, but its boundary is inferred
(where views stop and no other goes on), an aligned one's frames too, and its error grows with
the views' count as a session closes around the body. ``spectral-unions-train
calibrate-sessions`` measures both on anny sessions with exact truth and writes
:data:`~app.contract.SESSIONS_FILE`: per band of view counts and per eigenvalue, the relative σ
with which union ± INTERVAL_Z·σ holds 90 % of the calibration sessions' eigenvalues; and, per
band, whether unregistered views are read better aligned or through the learned chain (on the
calibration people; how often each held on held-out people is written beside).
"""

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Literal

import numpy as np

Unregistered = Literal["aligned", "learned-chain"]


@dataclass(frozen=True)
class Bands:
    """Relative σ per band: sessions of at most ``up_to[i]`` views use ``relative[i]`` (k,)."""

    up_to: tuple[int, ...]
    relative: np.ndarray

    @classmethod
    def of(cls, bands: list[dict], k: int, name: str) -> "Bands":
        relative = np.array([band["relative_sigma"] for band in bands], dtype=np.float64)
        if relative.shape != (len(bands), k) or not np.all(np.isfinite(relative)) or np.any(relative < 0):
            raise ValueError(f"{name}: relative_sigma must be {len(bands)} rows of {k} finite values ≥ 0")
        up_to = tuple(int(band["views_up_to"]) for band in bands)
        if not up_to or list(up_to) != sorted(set(up_to)):
            raise ValueError(f"{name}: bands must rise in views_up_to")
        return cls(up_to, relative)

    def band(self, views: int) -> int:
        """The band a session of ``views`` views falls in (the last beyond)."""
        return min(int(np.searchsorted(self.up_to, views)), len(self.up_to) - 1)

    def sigma(self, eigenvalues: np.ndarray, views: int) -> np.ndarray:
        """σ (1/m²) of a union of ``views`` views."""
        return self.relative[self.band(views)] * np.asarray(eigenvalues, dtype=np.float64)


@dataclass(frozen=True)
class SessionCalibration:
    """σ of fused (registered) and aligned unions, and how each aligned band is read."""

    fused: Bands
    aligned: Bands
    unregistered: tuple[Unregistered, ...]  # per aligned band

    @classmethod
    def load(cls, path: Path, k: int) -> "SessionCalibration":
        content = json.loads(path.read_text())
        methods = content["methods"]
        fused = Bands.of(methods["fused"]["bands"], k, f"{path.name} fused")
        aligned = Bands.of(methods["aligned"]["bands"], k, f"{path.name} aligned")
        unregistered = tuple(band["unregistered_by"] for band in methods["aligned"]["bands"])
        if not set(unregistered) <= {"aligned", "learned-chain"}:
            raise ValueError(f"{path.name}: unregistered_by must be aligned or learned-chain")
        return cls(fused, aligned, unregistered)

    def unregistered_by(self, views: int) -> Unregistered:
        """How a session of ``views`` unregistered views is read."""
        return self.unregistered[self.aligned.band(views)]
