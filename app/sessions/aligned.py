"""Views sent in their own frames brought into one, through where they lie on the template.

A scanner that does not track its camera sends each view in a frame of its own. Where the person
held one pose, the views are still one surface, and a rigid motion per view brings them
together; then their union is solved as registered views' is (:mod:`app.sessions.fused`) instead
of chaining the learned operator, which compounds. The correspondence model has placed every
view's points on the template, so two views' points placed near one template point are one
surface point: those pairs give each view's motion (a trimmed least-squares fit), which the views'
own points then refine (trimmed iterative closest points on the placed pairs' surroundings). A view
that already lies on the others where it was sent (a tracked camera's, sent without saying so) is
refined from there too, and the motion that closes the gap more is kept: places too far off to give
a motion (a child's, a close-up's) then cost nothing (decision 052).
Views are joined largest first, each next the one that shares most with those joined and comes
together with them (a view that does not yet is tried again once more views are joined). Where
some views never do (another pose, or places too wrong), the others are fused as far as those
left out hold at most :data:`MAX_LEFT_SHARE` of the area (the caller chains them onto that union
with the learned operator); beyond it the caller reads the session through the learned operator.
"""

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial import cKDTree

from app.sessions.fused import InsideRule, View, fused_spectrum

PLACE_MATCH_M = 0.03  # points placed this near on the template are taken for one surface point
MIN_PAIRS = 30  # fewer placed pairs do not fix a motion: the view waits for more of the union
TRIM = 0.7  # the share of pairs (the nearest) each fit keeps: places are a few cm off, some far
FIT_ROUNDS = 4
ICP_ROUNDS = 30
POINT_ROUNDS = 10  # the last rounds fit point to point
MAX_RESIDUAL = 0.25  # of the views' point spacing: a median gap to the union's surface above it is no fit
NORMAL_NEIGHBOURS = 8
ICP_POINTS = 1500  # about this many of a view's placed points refine its motion (every n-th)
OVERLAP_GAP = 1.5  # of the point spacing: a moved point this near the union lies on it


@dataclass(frozen=True)
class Motion:
    rotation: np.ndarray  # (3, 3)
    translation: np.ndarray  # (3,)

    def __call__(self, points: np.ndarray) -> np.ndarray:
        return points @ self.rotation.T + self.translation


AS_SENT = Motion(np.eye(3), np.zeros(3))


def rigid_fit(source: np.ndarray, target: np.ndarray) -> Motion:
    """The rotation and translation taking ``source`` (n, 3) nearest to ``target`` in least
    squares (Kabsch; a reflection is never returned)."""
    a, b = source.mean(axis=0), target.mean(axis=0)
    u, _, vt = np.linalg.svd((source - a).T @ (target - b))
    sign = np.sign(np.linalg.det(vt.T @ u.T)) or 1.0
    rotation = vt.T @ np.diag([1.0, 1.0, sign]) @ u.T
    return Motion(rotation, b - a @ rotation.T)


def trimmed_fit(source: np.ndarray, target: np.ndarray) -> Motion:
    """A rigid fit that keeps, round after round, the TRIM share of pairs it fits best."""
    keep = np.ones(len(source), bool)
    for _ in range(FIT_ROUNDS):
        motion = rigid_fit(source[keep], target[keep])
        gap = np.linalg.norm(motion(source) - target, axis=1)
        keep = gap <= np.quantile(gap, TRIM)
    return rigid_fit(source[keep], target[keep])


MAX_LEFT_SHARE = 0.25  # of a session's area: views left out of the alignment beyond this, it is not read aligned


@dataclass(frozen=True)
class Joined:
    """The views that came together, moved into the largest one's frame, and which they are
    (indices into the views given, in that order)."""

    views: list[View]
    indices: list[int]


def joined_views(views: list[View], places: list[np.ndarray]) -> Joined:
    """The views that come together, moved into the largest one's frame (see the module
    docstring); the largest always, the others as far as they join. ``places``: each view's
    points' places on the template (n, 3)."""
    order = np.argsort([-float(view.mass.sum()) for view in views], kind="stable")
    own_normals = [_normals(view.points, cKDTree(view.points)) for view in views]  # turned with each view
    moved: dict[int, Motion] = {int(order[0]): AS_SENT}
    waiting = [int(i) for i in order[1:]]
    spacing = float(np.median([_spacing(view.points) for view in views]))
    while waiting:
        joined = sorted(moved)
        union_points = np.concatenate([moved[i](views[i].points) for i in joined])
        normals = np.concatenate([own_normals[i] @ moved[i].rotation.T for i in joined])
        union_places = cKDTree(np.concatenate([places[i] for i in joined]))
        tree = cKDTree(union_points)
        pairs = {i: _placed_pairs(union_places, places[i]) for i in waiting}
        for candidate in sorted(waiting, key=lambda i: -int((pairs[i] >= 0).sum())):  # most shared first
            motion = _motion(views[candidate].points, pairs[candidate], union_points, tree, normals, spacing)
            if motion is not None:
                moved[candidate] = motion
                waiting.remove(candidate)
                break
        else:  # none of the views left comes together with those joined
            break
    indices = sorted(moved)
    return Joined([replace(views[i], points=moved[i](views[i].points)) for i in indices], indices)


def aligned_views(views: list[View], places: list[np.ndarray]) -> list[View] | None:
    """The views moved into the largest one's frame, in the order given; None where one of them
    cannot be brought to the others."""
    joined = joined_views(views, places)
    return joined.views if len(joined.indices) == len(views) else None


def _motion(
    points: np.ndarray, pairs: np.ndarray, union_points: np.ndarray, tree: cKDTree, normals: np.ndarray, spacing: float
) -> Motion | None:
    """The motion that brings a view's ``points`` onto the union's, refined from its placed
    ``pairs`` (each point's union point, −1 for none) and from where it was sent, where enough
    of it lies on the union as sent (views sent in one frame without saying so, their places a
    few cm off, or too far off to give a motion at all): whichever closes the gap more; None
    where neither closes it."""
    tried = []
    matched = pairs >= 0
    if matched.sum() >= MIN_PAIRS:
        fitted = points[matched][:: max(1, int(matched.sum()) // ICP_POINTS)]  # a spread-out subset: the cost
        placed = trimmed_fit(points[matched], union_points[pairs[matched]])
        tried.append(_refined(placed, fitted, tree, normals, spacing))
    sample = points[:: max(1, len(points) // ICP_POINTS)]
    on = tree.query(sample)[0] <= OVERLAP_GAP * spacing
    if on.sum() >= MIN_PAIRS:
        tried.append(_refined(AS_SENT, sample[on], tree, normals, spacing))
    motion, residual = min(tried, key=lambda fit: fit[1], default=(None, np.inf))
    return motion if residual <= MAX_RESIDUAL * spacing else None


@dataclass(frozen=True)
class AlignedUnion:
    """The first k eigenvalues of the views that came together, fused, and which views they are."""

    eigenvalues: np.ndarray
    joined: list[int]


def left_out(joined: list[int], views: int) -> list[int]:
    """The indices of ``views`` views not among ``joined``, in order."""
    return sorted(set(range(views)) - set(joined))


def aligned_union(
    views: list[View],
    places: list[np.ndarray],
    k: int,
    max_left_share: float = MAX_LEFT_SHARE,
    inside: InsideRule | None = None,
) -> AlignedUnion | None:
    """The union of the views that come together, fused (``inside``: as
    :func:`app.sessions.fused.fused_spectrum` reads it); None where those left out hold more
    than ``max_left_share`` of the views' area (the caller chains those left onto it: a view or
    two that do not come together, often a close-up, need not send the whole session through
    the learned chain, which compounds)."""
    joined = joined_views(views, places)
    left = left_out(joined.indices, len(views))
    area = [float(view.mass.sum()) for view in views]
    if sum(area[i] for i in left) > max_left_share * sum(area):
        return None
    joined_places = [places[i] for i in joined.indices]
    return AlignedUnion(fused_spectrum(joined.views, k, joined_places, inside), joined.indices)


def _placed_pairs(union_places: cKDTree, places: np.ndarray) -> np.ndarray:
    """For each point, the union point placed nearest it on the template (−1 beyond PLACE_MATCH_M)."""
    distance, nearest = union_places.query(places, distance_upper_bound=PLACE_MATCH_M)
    return np.where(np.isfinite(distance), nearest, -1)


def _refined(
    motion: Motion, points: np.ndarray, union: cKDTree, normals: np.ndarray, spacing: float
) -> tuple[Motion, float]:
    """Trimmed point-to-plane iterative closest points from ``motion``: each round, the moved
    points' nearest union points, the TRIM share nearest, and the small motion that best closes
    their gaps along the union's normals (which lets one sampling of a surface slide over
    another). Returns the motion and the median gap to the union's surface (infinite where too
    few points stay on it)."""
    for round_ in range(ICP_ROUNDS):
        moved = motion(points)
        gap, nearest = union.query(moved)
        keep = gap <= np.quantile(gap, TRIM)
        if round_ >= ICP_ROUNDS // 2:  # near: only the points that lie on the union (its overlap)
            keep &= gap <= OVERLAP_GAP * spacing
        if keep.sum() < MIN_PAIRS:  # the view has slid off the union: no fit
            return motion, np.inf
        p, q, n = moved[keep], union.data[nearest[keep]], normals[nearest[keep]]
        if round_ >= ICP_ROUNDS - POINT_ROUNDS:  # last: point to point, which holds what planes let slide
            motion = Motion(*_composed(rigid_fit(p, q), motion))
            continue
        system = np.column_stack([np.cross(p, n), n])
        step, *_ = np.linalg.lstsq(system, np.einsum("ij,ij->i", q - p, n), rcond=None)
        rotation = _small_rotation(step[:3])
        motion = Motion(rotation @ motion.rotation, motion.translation @ rotation.T + step[3:])
    moved = motion(points)
    gap, nearest = union.query(moved)
    on = gap <= OVERLAP_GAP * spacing
    if on.sum() < MIN_PAIRS:
        return motion, np.inf
    along = np.abs(np.einsum("ij,ij->i", moved[on] - union.data[nearest[on]], normals[nearest[on]]))
    return motion, float(np.median(along))


def _composed(after: Motion, before: Motion) -> tuple[np.ndarray, np.ndarray]:
    """The rotation and translation of ``after`` applied to what ``before`` moved."""
    return after.rotation @ before.rotation, before.translation @ after.rotation.T + after.translation


def _small_rotation(angles: np.ndarray) -> np.ndarray:
    """The rotation by the vector ``angles`` (axis times angle, radians: Rodrigues)."""
    angle = float(np.linalg.norm(angles))
    if angle < 1e-15:
        return np.eye(3)
    k = angles / angle
    cross = np.array([[0, -k[2], k[1]], [k[2], 0, -k[0]], [-k[1], k[0], 0]])
    return np.eye(3) + np.sin(angle) * cross + (1 - np.cos(angle)) * cross @ cross


def _normals(points: np.ndarray, tree: cKDTree) -> np.ndarray:
    """(n, 3) each point's surface normal: the least direction of its nearest points' spread."""
    _, nearest = tree.query(points, k=min(NORMAL_NEIGHBOURS, len(points)))
    local = points[nearest] - points[nearest].mean(axis=1, keepdims=True)
    _, _, vt = np.linalg.svd(local, full_matrices=False)
    return vt[:, 2]


def _spacing(points: np.ndarray) -> float:
    """A view's typical distance between neighbouring points."""
    if len(points) < 2:
        return 0.0
    distance, _ = cKDTree(points).query(points, k=2)
    return float(np.median(distance[:, 1]))
