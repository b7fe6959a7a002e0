"""A scanning session: its views as the service keeps them, and the union they make.

A front-end posts one view after another of one person. Each view is solved and placed on the
template once, when it arrives, and kept whole: its spectrum, its geometry (points, areas,
boundary) and where it lies on the template. The session's union is then read from all its
views at once, never from the union answered before, so no prediction is fed back in:

- one view: its own spectrum (measured, σ = 0);
- registered views (one frame and pose, as a tracked scanner sends them): the views fused and
  solved once (:mod:`app.sessions.fused`), σ from the sessions' calibration
  (:mod:`app.sessions.calibration`);
- views in their own frames or poses: the learned operator folded over the views' spectra,
  each step told what their places on the template say (:mod:`app.sessions.chain`).

Coverage is read from the views' places in every case.
"""

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from app.geometry.pipeline import Solved
from app.inference.correspondence import PlacedPart
from app.inference.cover import Cover, united
from app.inference.models import SpectralModels, UnionEstimate
from app.sessions.chain import Located, chained_union, template_fold
from app.sessions.fused import View, view_of_part

UnionBy = Literal["empty", "view", "fused", "learned-chain"]
LEAST_COVERED = 3  # the body parts a session answers as least covered: what to scan next


@dataclass(frozen=True)
class SessionView:
    """One view as a session keeps it: its name, spectrum (k,), geometry in the upload's frame
    (metres), place on the template and the warnings its solve and placing raised."""

    source: str
    eigenvalues: np.ndarray
    geometry: View
    located: Located
    warnings: tuple[str, ...]


@dataclass(frozen=True)
class SessionUnion:
    """The union of a session's views: the estimate and what made it; where the learned
    operator made it, each step's overlap read on the template and whether it was told it."""

    estimate: UnionEstimate
    union_by: UnionBy
    overlaps: list[float] = field(default_factory=list)
    overlaps_told: list[bool] = field(default_factory=list)


def union_by(views: int, registered: bool) -> UnionBy:
    """How a session of ``views`` views is read (the module docstring)."""
    if views == 0:
        return "empty"
    if views == 1:
        return "view"
    return "fused" if registered else "learned-chain"


def session_union(
    models: SpectralModels, views: list[SessionView], registered: bool, fused: np.ndarray | None = None
) -> SessionUnion:
    """The union of ``views``; ``fused``: the fused views' spectrum, where they are registered
    (solved by the caller, in a solver worker: :func:`app.sessions.fused.fused_spectrum`)."""
    by = union_by(len(views), registered)
    if by == "empty":
        return SessionUnion(UnionEstimate(np.zeros(0), np.zeros(0)), by)
    if by == "view":
        values = views[0].eigenvalues
        return SessionUnion(UnionEstimate(values, np.zeros_like(values)), by)
    if by == "fused":
        if fused is None or models.fused is None:
            raise ValueError("a registered session's union needs its fused spectrum and the sessions' calibration")
        return SessionUnion(UnionEstimate(fused, models.fused.sigma(fused, len(views))), by)
    fold = template_fold(models, [view.located for view in views])
    estimate = chained_union(models, [view.eigenvalues for view in views], fold)
    told = fold.told or [None] * len(fold.overlaps)
    steps = [share is not None or nested for share, nested in zip(told, estimate.nested, strict=True)]
    return SessionUnion(estimate, by, fold.overlaps, steps)


def session_cover(views: list[SessionView]) -> Cover | None:
    """What the session's views cover on the template together (None before the first)."""
    return united([view.located.cover for view in views]) if views else None


def least_covered(coverage: dict[str, float], count: int = LEAST_COVERED) -> list[str]:
    """The ``count`` body parts least covered, least first (ties by name): what to scan next."""
    return [name for name, _ in sorted(coverage.items(), key=lambda item: (item[1], item[0]))[:count]]


def session_view(source: str, solved: Solved, placed: PlacedPart, doubts: list[str]) -> SessionView:
    """An upload solved and placed (its part kept: the geometry the spectrum was solved on) as
    the view a session keeps; ``doubts``: what the placing found too uncertain to trust."""
    warnings = tuple(solved.report.warnings) + tuple(doubts)
    values = np.asarray(solved.report.eigenvalues, dtype=np.float64)
    return SessionView(source, values, view_of_part(solved.part), Located.placed(placed), warnings)
