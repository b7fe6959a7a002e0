"""Where each view's points find another view's, on the same stretch of the body.

A fused union reads every pair of views through one k-d tree query per ordered pair (each rule of
:mod:`app.sessions.fused` at its own scale): a point's nearest point of the other view, and how
far each view's own points lie apart there.

Nearness alone is not enough where the body nearly touches itself (an inner thigh against the
other, an arm against the torso): a point lies within a point spacing of another view's points on
the *other* stretch of surface, and taking them for its own drops a piece of the union and welds
the two stretches into one. Two points of one stretch face the same way; across such a gap they
face apart, so a point of a mesh view takes another mesh view's nearest point for its own only
where their normals turn the same way (each view's winding read from most of its pairs). Where
two views both stop at one rim (a foot's sole seen from below and its top from above) their
boundary points face apart and are still one place: boundary meeting boundary is left to the
rules that join loose ends. Point clouds carry no normals and are read by nearness alone
(``docs/decisions/051-a-view-finds-another-only-on-its-own-side.md``).
"""

from dataclasses import dataclass
from typing import Protocol

import numpy as np
import trimesh
from scipy.spatial import cKDTree

MIN_TOLERANCE_M = 0.003  # a few mm: one scanner's registered views rarely agree better
DUPLICATE = 0.5  # of the finer local spacing: a later view's point this near an earlier one's is the same point


class Surface(Protocol):
    """What a pair reads of a view (:class:`app.sessions.fused.View`)."""

    points: np.ndarray
    boundary: np.ndarray
    faces: np.ndarray | None


def reach(tree: cKDTree) -> np.ndarray:
    """(n,) how far each point's own neighbours lie (its second nearest): the view's local
    spacing, fine on a face or a hand, coarse on the back."""
    if tree.n < 3:
        return np.full(tree.n, MIN_TOLERANCE_M)
    distance, _ = tree.query(tree.data, k=3)
    return np.maximum(distance[:, 2], MIN_TOLERANCE_M)


@dataclass(frozen=True)
class Pair:
    """Where each point of one view finds its nearest point of another on its own stretch of
    surface, up to the farthest any rule looks: one k-d tree query per ordered pair, which every
    rule reads at its own scale."""

    distance: np.ndarray  # infinite where none is within reach, or the nearest faces away
    nearest: np.ndarray  # 0 where none
    reach: np.ndarray  # the view's own local spacing at each point
    other_reach: np.ndarray  # the other view's at each point's nearest

    def near(self, scale: float = 1.0, nearer: bool = False) -> np.ndarray:
        """Which points lie on the other view: its nearest point within either's local spacing
        (with ``nearer`` the smaller of the two), times ``scale``."""
        pick = np.minimum if nearer else np.maximum
        return self.distance <= scale * pick(self.reach, self.other_reach)

    def inside(self, other: Surface) -> np.ndarray:
        """Which points lie on the ``other`` view's inside: near one of its points that is not
        on its boundary."""
        return self.near() & ~other.boundary[self.nearest]

    def repeated(self) -> np.ndarray:
        """Which points are one of the other view's points again (within DUPLICATE of the finer
        spacing)."""
        return self.near(DUPLICATE, nearer=True)


def ordered_pairs(count: int) -> list[tuple[int, int]]:
    """Every ordered pair of ``count`` views."""
    return [(i, j) for i in range(count) for j in range(count) if i != j]


def every_pair(views: list[Surface], trees: list[cKDTree], farthest: float) -> dict[tuple[int, int], Pair]:
    """Where each view's points find the others' (``trees``: each view's k-d tree), up to
    ``farthest`` times the coarser local spacing, on their own side of the surface."""
    reaches = [reach(tree) for tree in trees]
    normals = [_vertex_normals(view) for view in views]
    pairs = {}
    for i, j in ordered_pairs(len(views)):
        bound = farthest * max(float(reaches[i].max(initial=0.0)), float(reaches[j].max(initial=0.0)))
        distance, nearest = trees[j].query(views[i].points, distance_upper_bound=bound)
        found = np.isfinite(distance)
        nearest = np.where(found, nearest, 0)
        if normals[i] is not None and normals[j] is not None:
            apart = _facing_apart(normals[i], normals[j][nearest], found)
            apart &= ~(views[i].boundary & views[j].boundary[nearest])
            distance, nearest = np.where(apart, np.inf, distance), np.where(apart, 0, nearest)
        pairs[i, j] = Pair(distance, nearest, reaches[i], reaches[j][nearest])
    return pairs


def _facing_apart(normals: np.ndarray, other_normals: np.ndarray, found: np.ndarray) -> np.ndarray:
    """(n,) which found pairs of points turn their normals apart (by more than a right angle),
    the other view's winding read from most found pairs: a view wound the other way round is no
    other surface."""
    along = np.einsum("ij,ij->i", normals, other_normals)
    winding = 1.0 if not found.any() or np.median(along[found]) >= 0 else -1.0
    return found & (winding * along <= 0)


def _vertex_normals(view: Surface) -> np.ndarray | None:
    """(n, 3) a mesh view's unit vertex normals as wound; None for a point cloud."""
    if view.faces is None:
        return None
    return np.asarray(trimesh.Trimesh(view.points, view.faces, process=False).vertex_normals)
