"""How much two uploaded views of one body overlap, measured where they share one frame.

A scanner that tracks its camera sends its views registered in one coordinate frame and one
pose; there the union operator's ``overlap`` (the share of the smaller part's area lying inside
the other) can be measured instead of guessed. Each solved shape leaves a :class:`Footprint`,
its vertices with their lumped areas (the mass matrix the spectrum was solved with); a point
of one view lies inside the other when the other has a vertex within the larger of the two
vertex spacings, and the shared area is the area of such points, counted from both sides.
"""

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

FOOTPRINT_POINTS = 32_768  # vertices kept per view (a random subset beyond), ~0.5 MB
UNION_POINTS = 4 * FOOTPRINT_POINTS  # the union so far of a chain is thinned to this many: bounded cost per step
MIN_TOLERANCE_M = 0.003  # registration of one scanner's views is rarely better than a few mm


@dataclass(frozen=True)
class Footprint:
    """A view's surface as points (n, 3) in metres with the area (m²) each stands for."""

    points: np.ndarray
    weights: np.ndarray

    @property
    def area(self) -> float:
        return float(self.weights.sum())

    @property
    def spacing(self) -> float:
        """The typical distance between neighbouring points: √(area per point)."""
        return float(np.sqrt(self.area / max(len(self.points), 1)))


def footprint_of(points: np.ndarray, areas: np.ndarray, limit: int = FOOTPRINT_POINTS) -> Footprint:
    """A solved shape's footprint: its vertices and lumped areas, a fixed random subset of
    ``limit`` of them (their areas scaled to the whole) when there are more."""
    weights = np.asarray(areas, dtype=np.float64)
    if len(points) > limit:
        kept = np.sort(np.random.default_rng(0).choice(len(points), limit, replace=False))
        points, weights = points[kept], weights[kept] * (weights.sum() / weights[kept].sum())
    return Footprint(np.asarray(points, dtype=np.float32), weights.astype(np.float32))


def _inside(points: Footprint, other: Footprint, tolerance: float) -> np.ndarray:
    """Which points of ``points`` have a point of ``other`` within ``tolerance``."""
    distance, _ = cKDTree(other.points).query(points.points, distance_upper_bound=tolerance)
    return np.isfinite(distance)


def measured_overlaps(views: list[Footprint]) -> list[float]:
    """The share of the smaller operand inside the other at each step of the left fold
    ((A ∪ B) ∪ C) ∪ …: the views so far (their union, each point counted once) against the next.
    0 … 1 per step, ``len(views) − 1`` of them."""
    shares = []
    so_far = views[0]
    for view in views[1:]:
        tolerance = max(so_far.spacing, view.spacing, MIN_TOLERANCE_M)
        of_next, of_so_far = _inside(view, so_far, tolerance), _inside(so_far, view, tolerance)
        shared = (view.weights[of_next].sum() + so_far.weights[of_so_far].sum()) / 2
        shares.append(float(np.clip(shared / min(so_far.area, view.area), 0.0, 1.0)))
        added = ~of_next  # the next view's points outside the union so far join it
        points = np.concatenate([so_far.points, view.points[added]])
        so_far = footprint_of(points, np.concatenate([so_far.weights, view.weights[added]]), UNION_POINTS)
    return shares
