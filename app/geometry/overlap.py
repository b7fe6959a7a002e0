"""How much two uploaded views of one body overlap, measured where they share one frame.

A scanner that tracks its camera sends its views registered in one coordinate frame and one
pose; there the union operator's ``overlap`` (the share of the smaller part's area lying inside
the other) can be measured instead of guessed. Each solved shape leaves a :class:`Footprint`,
its vertices with their lumped areas (the mass matrix the spectrum was solved with) and its
edge (the boundary vertices); a point of one view lies inside the other when the other has a
vertex within the larger of the two vertex spacings (or within a thinned point's spread, see
:class:`Footprint`), half inside when that vertex is on the other's edge (the band just past an
edge, counted whole, biased every share upward by ~0.03), and the shared area is the area of
such points, counted from both sides.

A client that sends views one by one and keeps only their spectra (the session page) keeps each
view's footprint instead of its geometry: a *footprint token* (:func:`footprint_token`), the
footprint thinned to WIRE_POINTS and packed as text, which ``POST /v1/overlap`` reads back.
"""

import base64
import binascii
from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

FOOTPRINT_POINTS = 32_768  # vertices kept per view (a random subset beyond), ~0.5 MB
UNION_POINTS = 4 * FOOTPRINT_POINTS  # the union so far of a chain is thinned to this many: bounded cost per step
MIN_TOLERANCE_M = 0.003  # registration of one scanner's views is rarely better than a few mm
# Points of a footprint token: 96 KiB of float32 (128 KiB as base64). Measured against full
# footprints in benchmarks/RESULTS.md (measured_overlap.py --points).
WIRE_POINTS = 4_096
MAX_TOKEN_COORDINATE_M = 1e4  # a token's coordinates and total area are those of a body in metres:
MAX_TOKEN_AREA_M2 = 1e4  # far past any, and bounded so that their squares and sums stay finite
TOKEN_PREFIX = "fp1."  # the token format's version: little-endian float32 rows (x, y, z, area, spread, edge)
_COLUMNS = 6
# A point whose nearest point of the other view is on that view's edge is counted half inside:
# the edge is where the other view stops, so half the area a point there stands for lies beyond.
EDGE_SHARE = 0.5
_ROW = np.dtype("<f4")


@dataclass(frozen=True)
class Footprint:
    """A view's surface as points (n, 3) in metres with the area (m²) each stands for, and how
    far (m) each point's area spreads where the footprint was thinned: 0 for a vertex of the
    mesh itself, √area for a point kept at random for many (its neighbours lie that far off);
    and which points are on the view's edge (its boundary vertices: where the view stops)."""

    points: np.ndarray
    weights: np.ndarray
    spread: np.ndarray
    edge: np.ndarray

    @property
    def area(self) -> float:
        return float(self.weights.sum())

    @property
    def spacing(self) -> float:
        """The typical distance between neighbouring points: √(area per point)."""
        return float(np.sqrt(self.area / max(len(self.points), 1)))


def footprint_of(
    points: np.ndarray,
    areas: np.ndarray,
    limit: int = FOOTPRINT_POINTS,
    spread: np.ndarray | None = None,
    edge: np.ndarray | None = None,
) -> Footprint:
    """A solved shape's footprint: its vertices, lumped areas and edge (boundary) vertices, a
    fixed random subset of ``limit`` of them when there are more (their areas scaled to the
    whole, their spread grown to match; edge and inner points thinned alike, so that which kind
    a point's nearest neighbour is does not depend on the thinning). ``spread``: the points'
    own, when they are an earlier footprint's."""
    weights = np.asarray(areas, dtype=np.float64)
    spread = np.zeros(len(weights)) if spread is None else np.asarray(spread, dtype=np.float64)
    edge = np.zeros(len(weights), dtype=bool) if edge is None else np.asarray(edge, dtype=bool)
    if len(points) > limit:
        kept = np.sort(np.random.default_rng(0).choice(len(points), limit, replace=False))
        points, weights, edge = points[kept], weights[kept] * (weights.sum() / weights[kept].sum()), edge[kept]
        spread = np.maximum(spread[kept], np.sqrt(weights))
    return Footprint(
        np.asarray(points, dtype=np.float32), weights.astype(np.float32), spread.astype(np.float32), edge.copy()
    )


@dataclass(frozen=True)
class _Reach:
    """Where each point of one footprint finds the other: ``near`` where the other has a point
    within ``reach`` (the tolerance, or the spread of either point where larger), ``nearest``
    that point (0 where not near). One k-d tree query serves both measures of a step."""

    near: np.ndarray
    nearest: np.ndarray
    reach: np.ndarray


def _reach(points: Footprint, other: Footprint, tolerance: float) -> _Reach:
    bound = max(tolerance, float(points.spread.max(initial=0.0)), float(other.spread.max(initial=0.0)))
    distance, nearest = cKDTree(other.points).query(points.points, distance_upper_bound=bound)
    found = np.isfinite(distance)
    reach = np.full(len(distance), tolerance)
    reach[found] = np.maximum(tolerance, np.maximum(points.spread[found], other.spread[nearest[found]]))
    near = found & (distance <= reach)
    return _Reach(near, np.where(near, nearest, 0), reach)


def _inside(points: Footprint, other: Footprint, found: _Reach) -> np.ndarray:
    """How much of each point of ``points`` lies inside ``other``: 1 where ``other`` has a point
    within ``tolerance``, or within the spread of either (a footprint thinned at random keeps
    points farther apart where its mesh was coarse than the mean spacing says: without it, two
    thinned views of one surface miss each other, 0.69 measured for a true 0.94 at 4 096
    points); EDGE_SHARE where that nearest point is on ``other``'s edge and the point is not
    near its own view's edge (the other view stops there, this one goes on); else 0."""
    share = np.zeros(len(points.points))
    inside = found.near
    beyond = other.edge[found.nearest[inside]] & ~_near_edge(points, inside, found.reach)  # else both views end there
    share[inside] = np.where(beyond, EDGE_SHARE, 1.0)
    return share


def _near_edge(points: Footprint, selected: np.ndarray, reach: np.ndarray) -> np.ndarray:
    """Which of the ``selected`` points have an edge point of their own view within their reach."""
    if not points.edge.any():
        return np.zeros(int(selected.sum()), dtype=bool)
    distance, _ = cKDTree(points.points[points.edge]).query(points.points[selected])
    return distance <= reach[selected]


def _edge_left(points: Footprint, other: Footprint, found: _Reach) -> np.ndarray:
    """How much of each of ``points``' edge points stays on the edge of its union with ``other``:
    0 where ``other``'s surface (an inner point) is within reach, which covers it; EDGE_SHARE
    where the nearest point within reach is on ``other``'s edge too (the views stop at one place,
    as a re-scan of one region does: that stretch of edge is counted once, half from each side);
    1 where ``other`` is not within reach. 0 for the points not on the edge."""
    left = np.where(found.near, np.where(other.edge[found.nearest], EDGE_SHARE, 0.0), 1.0)
    return np.where(points.edge, left, 0.0)


def _edge_length(footprint: Footprint, left: np.ndarray | None = None) -> float:
    """The length (m) of a footprint's edge, or of the part ``left`` of it: each edge point stands
    for √(its area) of edge, the spacing of the mesh around it."""
    weight = footprint.edge if left is None else left
    return float(np.sqrt(footprint.weights.astype(np.float64)) @ weight)


@dataclass(frozen=True)
class MeasuredFold:
    """What registered views tell of each step of the left fold ((A ∪ B) ∪ C) ∪ …: the overlap
    (share of the smaller operand inside the other), the boundary share (how much of the two
    operands' edge length is left on the union's edge: 0 closed, 1 neither covers any of the
    other's edge) and the footprint of the union of all the views (thinned to UNION_POINTS)."""

    overlaps: list[float]
    boundaries: list[float]
    union: Footprint


def measured_overlaps(views: list[Footprint]) -> list[float]:
    """The share of the smaller operand inside the other at each step of the left fold
    ((A ∪ B) ∪ C) ∪ …: the views so far (their union, each point counted once) against the next.
    0 … 1 per step, ``len(views) − 1`` of them."""
    return measured_fold(views).overlaps


def measured_fold(views: list[Footprint]) -> MeasuredFold:
    """:func:`measured_overlaps`, each step's boundary share, and the footprint of the union of
    all the views: what a client sends instead of the earlier views when the next one comes."""
    shares, boundaries = [], []
    so_far = views[0]
    for view in views[1:]:
        tolerance = max(so_far.spacing, view.spacing, MIN_TOLERANCE_M)
        to_so_far, to_next = _reach(view, so_far, tolerance), _reach(so_far, view, tolerance)
        of_next, of_so_far = _inside(view, so_far, to_so_far), _inside(so_far, view, to_next)
        shared = (view.weights @ of_next + so_far.weights @ of_so_far) / 2
        shares.append(float(np.clip(shared / min(so_far.area, view.area), 0.0, 1.0)))
        left_so_far, left_next = _edge_left(so_far, view, to_next), _edge_left(view, so_far, to_so_far)
        edges = _edge_length(so_far) + _edge_length(view)
        kept = _edge_length(so_far, left_so_far) + _edge_length(view, left_next)
        boundaries.append(float(np.clip(kept / edges, 0.0, 1.0)) if edges > 0 else 0.0)
        added = of_next == 0  # the next view's points outside the union so far join it
        # The union's edge: the views' edge points that the other view does not cover (where both
        # stop at one place, the union stops there too: the union so far's point stays).
        edge = np.concatenate([left_so_far > 0, view.edge[added]])
        points = np.concatenate([so_far.points, view.points[added]])
        weights = np.concatenate([so_far.weights, view.weights[added]])
        spread = np.concatenate([so_far.spread, view.spread[added]])
        so_far = footprint_of(points, weights, UNION_POINTS, spread, edge)
    return MeasuredFold(shares, boundaries, so_far)


def footprint_token(footprint: Footprint) -> str:
    """A footprint as text a client can keep and send back: thinned to WIRE_POINTS points,
    rows (x, y, z in metres, area in m², spread in m, edge 0 or 1) as little-endian float32, base64."""
    thinned = footprint_of(footprint.points, footprint.weights, WIRE_POINTS, footprint.spread, footprint.edge)
    rows = np.column_stack([thinned.points, thinned.weights, thinned.spread, thinned.edge]).astype(_ROW)
    return TOKEN_PREFIX + base64.b64encode(rows.tobytes()).decode("ascii")


def footprint_from_token(token: str) -> Footprint:
    """A footprint token read back; ``ValueError`` saying why it is not one (not a token, not
    whole rows, over WIRE_POINTS points, values not finite, areas not positive, spreads negative,
    edge flags other than 0 and 1, anything past a body's size in metres)."""
    if not isinstance(token, str) or not token.startswith(TOKEN_PREFIX):
        raise ValueError(f"not a footprint token (they start with {TOKEN_PREFIX!r})")
    body = token[len(TOKEN_PREFIX) :]
    if len(body) > 4 * ((WIRE_POINTS * _COLUMNS * _ROW.itemsize + 2) // 3):  # checked before decoding
        raise ValueError(f"holds more than {WIRE_POINTS} points")
    try:
        raw = base64.b64decode(body, validate=True)
    except (binascii.Error, ValueError):
        raise ValueError("is not valid base64") from None
    if not raw or len(raw) % (_COLUMNS * _ROW.itemsize):
        raise ValueError("does not hold whole (x, y, z, area, spread, edge) rows")
    rows = np.frombuffer(raw, dtype=_ROW).reshape(-1, _COLUMNS)
    if not np.isfinite(rows).all():
        raise ValueError("holds values that are not finite")
    if (np.abs(rows[:, :3]) > MAX_TOKEN_COORDINATE_M).any() or (rows[:, 4] > MAX_TOKEN_COORDINATE_M).any():
        raise ValueError(f"holds coordinates or spreads beyond {MAX_TOKEN_COORDINATE_M:g} m")
    if (rows[:, 4] < 0).any():
        raise ValueError("holds negative spreads")
    if not np.isin(rows[:, 5], (0.0, 1.0)).all():
        raise ValueError("holds edge flags other than 0 and 1")
    if not (rows[:, 3] > 0).all() or rows[:, 3].astype(np.float64).sum() > MAX_TOKEN_AREA_M2:
        raise ValueError(f"holds areas that are not positive or sum past {MAX_TOKEN_AREA_M2:g} m²")
    return Footprint(rows[:, :3].copy(), rows[:, 3].copy(), rows[:, 4].copy(), rows[:, 5] == 1.0)
