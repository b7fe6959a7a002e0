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
  (:mod:`app.sessions.aligned`); where a few views, at most a quarter of the area, do not come
  together, those chained onto the others' fused union by the learned operator; otherwise, or
  where more do not (another pose), the learned operator folded over the views' spectra, each
  step told what their places on the template say (:mod:`app.sessions.chain`).

Coverage is read from the views' places in every case.
"""

from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np

from app.geometry.pipeline import Solved
from app.geometry.placing import Part
from app.inference.correspondence import PlacedPart
from app.inference.cover import Cover, united
from app.inference.models import SpectralModels, UnionEstimate
from app.sessions.aligned import AlignedUnion, left_out
from app.sessions.calibration import Bands, SessionCalibration
from app.sessions.chain import Located, folded_union
from app.sessions.fused import View, view_of_part

UnionBy = Literal["empty", "view", "fused", "aligned", "aligned-and-chained", "learned-chain"]
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
    operator made it, each step's overlap and boundary share read on the template and whether
    it was told them."""

    estimate: UnionEstimate
    union_by: UnionBy
    overlaps: list[float] = field(default_factory=list)
    overlaps_told: list[bool] = field(default_factory=list)
    boundaries: list[float] = field(default_factory=list)


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
    models: SpectralModels, views: list[SessionView], by: UnionBy, solved: np.ndarray | AlignedUnion | None = None
) -> SessionUnion:
    """The union of ``views`` read ``by`` (:func:`union_by`, or learned-chain where aligning
    failed); ``solved``: for fused, the spectrum the caller solved on the views, for aligned the
    union of those that came together (in a solver worker: :func:`app.sessions.fused.
    fused_spectrum`, :func:`app.sessions.aligned.aligned_union`)."""
    if by == "empty":
        return SessionUnion(UnionEstimate(np.zeros(0), np.zeros(0)), by)
    if by == "view":
        values = views[0].eigenvalues
        return SessionUnion(UnionEstimate(values, np.zeros_like(values)), by)
    if by in ("fused", "aligned") and (solved is None or models.sessions is None):
        raise ValueError(f"a {by} union needs its spectrum and the sessions' calibration")
    if by == "fused":
        return SessionUnion(UnionEstimate(solved, models.sessions.fused.sigma(solved, len(views))), by)
    if by == "aligned" and len(solved.joined) == len(views):
        values = solved.eigenvalues
        return SessionUnion(UnionEstimate(values, models.sessions.aligned.sigma(values, len(views))), by)
    if by == "aligned":
        return _aligned_and_chained(models, views, solved)
    return _chained(models, [view.eigenvalues for view in views], [view.located for view in views], by)


def _aligned_and_chained(models: SpectralModels, views: list[SessionView], aligned: AlignedUnion) -> SessionUnion:
    """:func:`chained_onto_aligned`, σ as :func:`aligned_and_chained_sigma` gives it."""
    union = chained_onto_aligned(models, views, aligned)
    estimate = union.estimate
    sigma = aligned_and_chained_sigma(estimate, models.sessions.aligned, len(views))
    return replace(union, estimate=UnionEstimate(estimate.eigenvalues, sigma, estimate.nested))


def chained_onto_aligned(models: SpectralModels, views: list[SessionView], aligned: AlignedUnion) -> SessionUnion:
    """The views that came together, fused, then the few left out chained onto that union by the
    learned operator (its region the joined views' covers united): a step or two of the chain
    instead of one per view; σ the chain's alone."""
    left = left_out(aligned.joined, len(views))
    joined_cover = united([views[i].located.counted for i in aligned.joined])
    located = [Located.carried(joined_cover, models.vertex_area)] + [views[i].located for i in left]
    values = [aligned.eigenvalues] + [views[i].eigenvalues for i in left]
    return _chained(models, values, located, "aligned-and-chained")


def aligned_and_chained_sigma(chained: UnionEstimate, aligned: Bands, views: int) -> np.ndarray:
    """σ of an aligned-and-chained union: the chain's steps' and an aligned union's of this many
    views together (independent errors)."""
    return np.hypot(chained.sigma, aligned.sigma(chained.eigenvalues, views))


def _chained(models: SpectralModels, values: list[np.ndarray], located: list[Located], by: UnionBy) -> SessionUnion:
    """The learned operator folded over ``values``, each step told what ``located`` says."""
    folded = folded_union(models, values, located, None, None, None)
    return SessionUnion(folded.result, by, folded.overlaps, folded.told, folded.boundaries)


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
    return placed_view(source, solved.report.eigenvalues, solved.part, placed, warnings)


def placed_view(
    source: str, eigenvalues: list[float], part: Part, placed: PlacedPart, warnings: tuple[str, ...] = ()
) -> SessionView:
    """A part with its spectrum and its places as the view a session keeps (a union route's
    uploads are read as one)."""
    values = np.asarray(eigenvalues, dtype=np.float64)
    return SessionView(source, values, view_of_part(part), placed.placement.position, Located.placed(placed), warnings)
