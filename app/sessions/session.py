"""A scanning session: its views as the service keeps them, and the union they make.

A front-end posts one view after another of one person. Each view is solved and placed on the
template once, when it arrives, and kept whole: its spectrum, its geometry (points, areas,
boundary) and where it lies on the template. The session's union is then read from all its
views at once, never from the union answered before, so no prediction is fed back in:

- one view: its own spectrum (measured, σ = 0);
- registered views (one frame and pose, as a tracked scanner sends them): the views fused and
  solved once (:mod:`app.sessions.fused`), σ from the sessions' calibration
  (:mod:`app.sessions.calibration`);
- views in their own frames: where the calibration found it closer for sessions of this many
  views, the views brought into one frame through their places on the template and fused
  (:mod:`app.sessions.aligned`); otherwise, or where they do not come together (another pose),
  the learned operator folded over the views' spectra, each step told what their places on the
  template say (:mod:`app.sessions.chain`).

Coverage is read from the views' places in every case.
"""

from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from app.geometry.pipeline import Solved
from app.inference.correspondence import PlacedPart
from app.inference.cover import Cover, united
from app.inference.models import SpectralModels, UnionEstimate
from app.sessions.calibration import SessionCalibration
from app.sessions.chain import Located, chained_union, template_fold
from app.sessions.fused import View, view_of_part

UnionBy = Literal["empty", "view", "fused", "aligned", "learned-chain"]
LEAST_COVERED = 3  # the body parts a session answers as least covered: what to scan next


@dataclass(frozen=True)
class SessionView:
    """One view as a session keeps it: its name, spectrum (k,), geometry in the upload's frame
    (metres), its points' places on the template (n, 3), where it lies there, and the warnings
    its solve and placing raised."""

    source: str
    eigenvalues: np.ndarray
    geometry: View
    places: np.ndarray
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


def union_by(views: int, registered: bool, calibration: SessionCalibration | None) -> UnionBy:
    """How a session of ``views`` views is read (the module docstring): fused or aligned only
    with the calibration that gives their σ."""
    if views == 0:
        return "empty"
    if views == 1:
        return "view"
    if calibration is None:
        return "learned-chain"
    return "fused" if registered else calibration.unregistered_by(views)


def session_union(
    models: SpectralModels, views: list[SessionView], by: UnionBy, solved: np.ndarray | None = None
) -> SessionUnion:
    """The union of ``views`` read ``by`` (:func:`union_by`, or learned-chain where aligning
    failed); ``solved``: for fused and aligned, the spectrum the caller solved on the views (in a
    solver worker: :func:`app.sessions.fused.fused_spectrum`,
    :func:`app.sessions.aligned.aligned_spectrum`)."""
    if by == "empty":
        return SessionUnion(UnionEstimate(np.zeros(0), np.zeros(0)), by)
    if by == "view":
        values = views[0].eigenvalues
        return SessionUnion(UnionEstimate(values, np.zeros_like(values)), by)
    if by in ("fused", "aligned"):
        if solved is None or models.sessions is None:
            raise ValueError(f"a {by} union needs its spectrum and the sessions' calibration")
        bands = models.sessions.fused if by == "fused" else models.sessions.aligned
        return SessionUnion(UnionEstimate(solved, bands.sigma(solved, len(views))), by)
    fold = template_fold(models, [view.located for view in views])
    estimate = chained_union(models, [view.eigenvalues for view in views], fold)
    told = fold.told or [None] * (len(views) - 1)
    steps = [share is not None or nested for share, nested in zip(told, estimate.nested, strict=True)]
    return SessionUnion(estimate, by, fold.overlaps, steps)


def session_cover(views: list[SessionView]) -> Cover | None:
    """What the session's views cover on the template together (None before the first)."""
    return united([view.located.counted for view in views]) if views else None


def session_coverage(models: SpectralModels, views: list[SessionView]) -> dict[str, float]:
    """Each body part's covered share by the views together (none before the first view)."""
    cover = session_cover(views)
    if cover is None:
        return {}
    return models.region_of(cover.region, cover.share).part_coverage


def least_covered(coverage: dict[str, float], count: int = LEAST_COVERED) -> list[str]:
    """The ``count`` body parts least covered, least first (ties by name): what to scan next."""
    return [name for name, _ in sorted(coverage.items(), key=lambda item: (item[1], item[0]))[:count]]


def session_view(source: str, solved: Solved, placed: PlacedPart, doubts: list[str]) -> SessionView:
    """An upload solved and placed (its part kept: the geometry the spectrum was solved on) as
    the view a session keeps; ``doubts``: what the placing found too uncertain to trust."""
    warnings = tuple(solved.report.warnings) + tuple(doubts)
    values = np.asarray(solved.report.eigenvalues, dtype=np.float64)
    geometry, places = view_of_part(solved.part), placed.placement.position
    return SessionView(source, values, geometry, places, Located.placed(placed), warnings)
