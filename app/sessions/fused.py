"""The spectrum of a union of views that share one frame, solved once on the views themselves.

Chaining the learned union operator feeds each prediction back in, and its error compounds: on
anny sessions of 12 and 24 views it is tens of per cent off where the views fused here are a few
(``docs/decisions/036-a-session-is-solved-on-its-fused-views.md``). Where the views' geometry is
at hand in one frame (a tracked scanner's), nothing needs predicting: the union is the views'
points, each surface point counted once (the largest view's where views overlap, so any order or
grouping of the views gives one union), with the Dirichlet boundary where a view stops and no
other view goes on, and its spectrum is solved once: on the views' own triangles glued together
where every view is a mesh, else as an uploaded point cloud is.

What decides the answer is the union's boundary. A view's boundary point is inside the union where
another view's inside is within reach (the local spacing of either view, at least
:data:`~app.sessions.pairs.MIN_TOLERANCE_M`); where two views stop side by side facing each other,
the gap between them is a seam, not a boundary; where both stop at one place on the same side (a
re-scan), the union stops there too. A point finds another view's only on its own stretch of the
body, not across a gap where the body nearly touches itself (:mod:`app.sessions.pairs`). The points
left on the boundary are joined into loops (along each view's boundary edges, and across views
where their loose ends meet); a closed loop no longer than :data:`~app.contract.MAX_HOLE_EDGES`
boundary edges is a pin-hole between views and is capped (its points freed, a point at its centre
added), as the spectrum definition caps a mesh's pin-holes: without it, the gaps views leave
between them pin a nearly closed union to zero and every eigenvalue comes out too high. A few
boundary points that make no curve with any other are freed for the same reason. What the views'
geometry cannot tell (whether a seam a face wide between two views is covered), another reading can
(``inside``: :mod:`app.sessions.seen`). These rules, not the glued Laplacian, are what a registered
session's error is left in; the readings tried in their place are measured in
``docs/decisions/046-the-fused-boundary-stays-rule-based.md`` and
``050-a-session-boundary-is-not-decided-by-loops-or-thresholds.md``.

A view whose every point lies on another view adds nothing and goes first (a re-scan, a close-up,
a part sent with its re-meshed copy: the union is the other view, exactly). Where every view is
a mesh, the spectrum is solved on the views glued through their own triangles
(:mod:`app.sessions.seams`), not on the points.
"""

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from app.contract import MAX_HOLE_EDGES
from app.geometry.pipeline import SpectrumOptions, cloud_spectrum
from app.geometry.placing import Part
from app.geometry.shapes import PointCloud
from app.geometry.topology import boundary_half_edges
from app.sessions.pairs import Pair, every_pair, ordered_pairs
from app.sessions.seams import Seams, cap_fans, glued_spectrum, welded_faces

BRIDGE = 0.9  # of the coarser local spacing: two views' loose ends this near, facing, are one seam
INWARD_NEIGHBOURS = 8  # a boundary point's own neighbours that say which way its view lies
MEET = 2.0  # of the coarser local spacing: two views' loose ends this near are one stretch of a loop
FARTHEST = max(1.0, BRIDGE, MEET)  # the farthest any rule looks
FRAGMENT_POINTS = 4  # boundary points fewer than this, joined to no other, are no boundary
FRAGMENT_REACH = 3.0  # of the local spacing: how near two boundary points are to be one curve
COVERED_SHARE = 0.001  # of a view's area: a view with no more than this off every other view adds nothing


@dataclass(frozen=True)
class View:
    """One view's surface in the session's frame: ``points`` (n, 3) metres, ``mass`` (n,) the
    lumped area of each (m²), ``boundary`` (n,) its boundary points, ``edges`` (e, 2) the
    boundary edges joining them (a mesh's boundary half-edges; for a point cloud, each boundary
    point to its nearest boundary neighbours), ``faces`` (m, 3) a mesh's triangles (None for a
    point cloud)."""

    points: np.ndarray
    mass: np.ndarray
    boundary: np.ndarray
    edges: np.ndarray
    faces: np.ndarray | None = None


@dataclass(frozen=True)
class FusedCloud:
    """The union's points, each surface point once: ``points`` (n, 3), ``boundary`` (n,) held at
    zero, how many pin-holes between views were capped, where every view is a mesh the views'
    triangles glued over the points (:mod:`app.sessions.seams`; None otherwise), and how many views it was
    made of (those another view held whole left out)."""

    points: np.ndarray
    boundary: np.ndarray
    capped: int
    faces: np.ndarray | None = None
    views: int = 1

    def freed(self, inside: np.ndarray) -> "FusedCloud":
        """The cloud with the boundary points ``inside`` (n,) freed, and the fragments that
        leaves (:func:`_without_fragments`)."""
        return replace(self, boundary=_without_fragments(self.points, self.boundary & ~inside))


# (views in one frame, each point's place on the template, their fused cloud) → (n,) which of the
# cloud's boundary points another reading finds inside the union (:mod:`app.sessions.seen`)
InsideRule = Callable[[list["View"], list[np.ndarray], FusedCloud], np.ndarray]


def fused_cloud(views: list[View]) -> FusedCloud:
    """The union of ``views`` (one frame): each surface point once (the larger view's where two
    cover it), its boundary where a view stops and no other's inside goes on, the pin-holes
    between views capped; a view another holds whole left out first. Costs a k-d tree query per
    pair of views."""
    trees = [cKDTree(view.points) for view in views]
    every = every_pair(views, trees, FARTHEST)
    gone = covered_views(views, every)
    order = [i for i in canonical_order(views) if i not in gone]
    if len(order) == 1:  # one view is its own union: its points, boundary and triangles as solved
        (alone,) = (views[i] for i in order)
        return FusedCloud(alone.points, alone.boundary.copy(), 0, alone.faces)
    pairs = {(a, b): every[order[a], order[b]] for a, b in ordered_pairs(len(order))}
    views, trees = [views[i] for i in order], [trees[i] for i in order]
    kept, under, loose = _overlapped(views, pairs)
    seamed = _bridge(views, trees, pairs, loose)
    pinholes, loops = _pinholes(views, pairs, loose, kept)
    centres = np.array([loop.mean(axis=0) for loop in loops], dtype=np.float64).reshape(-1, 3)
    points = [view.points[keep] for view, keep in zip(views, kept, strict=True)]
    boundary = [(edge & ~hole)[keep] for keep, edge, hole in zip(kept, loose, pinholes, strict=True)]
    cloud, flags = np.concatenate(points + [centres]), np.concatenate(boundary + [np.zeros(len(centres), bool)])
    flags |= _edges_of_dropped(views, kept, loose, pinholes, cloud)
    faces = None
    if all(view.faces is not None for view in views):
        seams = [Seams(v.faces, k, u, ~k | s) for v, k, u, s in zip(views, kept, under, seamed, strict=True)]
        faces = _glued(views, seams, cloud, loops)
    return FusedCloud(cloud, _without_fragments(cloud, flags), len(centres), faces, len(views))


def _overlapped(
    views: list[View], pairs: dict[tuple[int, int], Pair]
) -> tuple[list[np.ndarray], list[np.ndarray], list[np.ndarray]]:
    """Per view (in canonical order): which points the union keeps (not on an earlier view's
    inside, nor one of its points again), which lie on an earlier view's inside, and which
    boundary points no other view's inside covers."""
    kept = [np.ones(len(view.points), bool) for view in views]
    under = [np.zeros(len(view.points), bool) for view in views]
    loose = [view.boundary.copy() for view in views]
    for (i, j), pair in pairs.items():
        inside = pair.inside(views[j])
        if j < i:  # a larger view's inside, or one of its points, is already there
            kept[i] &= ~(inside | pair.repeated())
            under[i] |= inside
        loose[i] &= ~inside
    return kept, under, loose


def covered_views(views: list[View], pairs: dict[tuple[int, int], Pair]) -> set[int]:
    """The views another view holds whole (all but COVERED_SHARE of their area on its inside or
    on its boundary points themselves), which add nothing to the union. Of views that hold each
    other (a part and its re-meshed copy) the one with more points stays: the finer mesh."""
    gone: set[int] = set()
    keys = [(len(view.points), float(view.mass.sum()), float(view.points.sum())) for view in views]
    for i in sorted(range(len(views)), key=keys.__getitem__):  # the coarser first: whatever order they came in
        for j in range(len(views)):
            if j == i or j in gone:
                continue
            pair = pairs[i, j]
            on = pair.inside(views[j]) | pair.repeated()
            if float(views[i].mass[~on].sum()) <= COVERED_SHARE * float(views[i].mass.sum()):
                gone.add(i)
                break
    return gone


def _glued(views: list[View], seams: list[Seams], cloud: np.ndarray, loops: list[np.ndarray]) -> np.ndarray:
    """The views' own triangles over the cloud's points, welded at the seams, and a fan capping
    each pin-hole (its points ``loops[h]``, its centre the cloud's ``h``-th of the last
    ``len(loops)`` points)."""
    owner = np.concatenate([np.full(int(seam.kept.sum()), index) for index, seam in enumerate(seams)])
    owner = np.concatenate([owner, np.full(len(loops), -1)])
    tree = cKDTree(cloud)
    glued = welded_faces([view.points for view in views], seams, tree, owner)
    rings = [tree.query(loop)[1] for loop in loops]
    first = len(cloud) - len(loops)
    return np.concatenate([glued, cap_fans(cloud, rings, cloud[first:], first)])


def _without_fragments(points: np.ndarray, flags: np.ndarray) -> np.ndarray:
    """``flags`` less the boundary points that make no curve: fewer than FRAGMENT_POINTS of them
    with no other boundary point within FRAGMENT_REACH local spacings. A boundary is a curve;
    such fragments are what the seam rules leave where views meet at a notch, and on a nearly
    closed union each one pins the surface to zero around it and lifts every eigenvalue."""
    flagged = np.flatnonzero(flags)
    if len(flagged) == 0:
        return flags
    reach = cKDTree(points).query(points[flagged], k=min(3, len(points)))[0][:, -1]
    at = points[flagged]
    pairs = cKDTree(at).query_pairs(FRAGMENT_REACH * float(reach.max()), output_type="ndarray").reshape(-1, 2)
    distance = np.linalg.norm(at[pairs[:, 0]] - at[pairs[:, 1]], axis=1)
    pairs = pairs[distance <= FRAGMENT_REACH * np.maximum(reach[pairs[:, 0]], reach[pairs[:, 1]])]
    graph = sp.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), (len(flagged), len(flagged)))
    _, label = connected_components(graph, directed=False)
    kept = flags.copy()
    kept[flagged[np.bincount(label)[label] < FRAGMENT_POINTS]] = False
    return kept


def _inward(view: View, tree: cKDTree, points: np.ndarray) -> np.ndarray:
    """(m, 3) unit directions from each of ``points`` (boundary points of ``view``, whose k-d
    tree is ``tree``) into the view: towards the mean of its nearest points."""
    _, nearest = tree.query(points, k=min(INWARD_NEIGHBOURS, len(view.points)))
    direction = view.points[nearest].mean(axis=1) - points
    return direction / np.maximum(np.linalg.norm(direction, axis=1, keepdims=True), 1e-12)


def _bridge(
    views: list[View], trees: list[cKDTree], pairs: dict[tuple[int, int], Pair], loose: list[np.ndarray]
) -> list[np.ndarray]:
    """Two views that stop side by side, facing each other across less than a spacing, join
    there (the gap between them is a seam, not a boundary): their loose points that meet a loose
    point of the other view going the other way are no longer loose. Two views that stop at one
    place on the same side (a re-scan) keep that boundary. Returns, for each view, its points so
    joined to an earlier view's (where glued, welded onto them)."""
    inward = [np.zeros((len(view.points), 3)) for view in views]
    for view, tree, edge, direction in zip(views, trees, loose, inward, strict=True):
        if edge.any():
            direction[edge] = _inward(view, tree, view.points[edge])
    joined = [np.zeros(len(view.points), bool) for view in views]
    earlier = [np.zeros(len(view.points), bool) for view in views]
    for (i, j), pair in pairs.items():
        if not loose[i].any() or not loose[j].any():
            continue
        meets = loose[i] & pair.near(BRIDGE) & loose[j][pair.nearest]
        facing = np.einsum("ij,ij->i", inward[i][meets], inward[j][pair.nearest[meets]]) < 0
        seam = np.flatnonzero(meets)[facing]
        joined[i][seam] = True
        if j < i:
            earlier[i][seam] = True
    for edge, join in zip(loose, joined, strict=True):
        edge &= ~join
    return earlier


def canonical_order(views: list[View]) -> list[int]:
    """The order views are fused in, whatever order they came in: the largest first (its points
    stand where views overlap), so that any order or grouping of one session's views gives one
    union."""
    keys = [(-float(view.mass.sum()), -len(view.points), float(view.points.sum())) for view in views]
    return sorted(range(len(views)), key=keys.__getitem__)


def _pinholes(
    views: list[View], pairs: dict[tuple[int, int], Pair], loose: list[np.ndarray], kept: list[np.ndarray]
) -> tuple[list[np.ndarray], list[np.ndarray]]:
    """Which loose boundary points lie on a pin-hole between views (a closed loop of at most
    MAX_HOLE_EDGES of the views' boundary edges, each stretch counted once: by the points the
    union keeps), and each such hole's points (n, 3)."""
    offsets = np.cumsum([0] + [len(view.points) for view in views])
    rows, cols, lengths = [], [], np.zeros(offsets[-1])
    for i, view in enumerate(views):
        a, b = view.edges[:, 0], view.edges[:, 1]
        both = loose[i][a] & loose[i][b]
        rows.append(a[both] + offsets[i])
        cols.append(b[both] + offsets[i])
        length = np.linalg.norm(view.points[a[both]] - view.points[b[both]], axis=1)
        np.add.at(lengths, a[both] + offsets[i], kept[i][a[both]] * length / 2)
        np.add.at(lengths, b[both] + offsets[i], kept[i][b[both]] * length / 2)
    for (i, j), pair in pairs.items():  # loose ends of two views that meet
        if loose[i].any() and loose[j].any():
            meets = np.flatnonzero(loose[i] & pair.near(MEET) & loose[j][pair.nearest])
            rows.append(meets + offsets[i])
            cols.append(pair.nearest[meets] + offsets[j])
    size = offsets[-1]
    graph = sp.coo_matrix((np.ones(sum(map(len, rows))), (np.concatenate(rows), np.concatenate(cols))), (size, size))
    graph = (graph + graph.T).tocsr()
    graph.data[:] = 1
    _, label = connected_components(graph, directed=False)
    on_loop = np.concatenate(loose)
    spacing = np.median([_edge_length(view) for view in views if len(view.edges)] or [0.0])
    count = label.max() + 1
    loop_length = np.bincount(label, weights=lengths * on_loop, minlength=count)
    loop_points = np.bincount(label, weights=on_loop, minlength=count)
    # A loop closes: every point on it has two neighbours. A piece of a long boundary whose
    # ends the other views' insides cut off is not a hole.
    open_ends = np.bincount(label, weights=on_loop & (np.diff(graph.indptr) < 2), minlength=count)
    small = (loop_points > 0) & (open_ends == 0) & (loop_length <= MAX_HOLE_EDGES * spacing)
    hole = on_loop & small[label]
    everything = np.concatenate([view.points for view in views])
    loops = [everything[hole & (label == loop)] for loop in np.unique(label[hole])]
    split = [hole[offsets[i] : offsets[i + 1]] for i in range(len(views))]
    return split, loops


def _edge_length(view: View) -> float:
    """The median length of a view's boundary edges."""
    return float(np.median(np.linalg.norm(view.points[view.edges[:, 0]] - view.points[view.edges[:, 1]], axis=1)))


def _edges_of_dropped(
    views: list[View], kept: list[np.ndarray], loose: list[np.ndarray], pinholes: list[np.ndarray], cloud: np.ndarray
) -> np.ndarray:
    """The union's boundary where it runs through points dropped as duplicates (a re-scan that
    stops where the first scan stops): the kept point each such point fell on is flagged."""
    parts = zip(views, kept, loose, pinholes, strict=True)
    dropped = [view.points[edge & ~hole & ~keep] for view, keep, edge, hole in parts]
    points = np.concatenate(dropped)
    flags = np.zeros(len(cloud), bool)
    if len(points):
        flags[cKDTree(cloud).query(points)[1]] = True
    return flags


def view_of(points: np.ndarray, mass: np.ndarray, boundary: np.ndarray, faces: np.ndarray | None) -> View:
    """A solved part as a view: a mesh's boundary edges from its faces; a point cloud's joining
    each boundary point to its two nearest boundary neighbours (a boundary is a curve)."""
    if faces is not None:
        edges = boundary_half_edges(faces)
        faces = np.asarray(faces, np.int64)
    else:
        ends = np.flatnonzero(boundary)
        if len(ends) > 2:
            _, nearest = cKDTree(points[ends]).query(points[ends], k=3)
            edges = np.column_stack([np.repeat(ends, 2), ends[nearest[:, 1:]].ravel()])
        else:
            edges = np.empty((0, 2), np.int64)
    return View(np.asarray(points, np.float64), np.asarray(mass, np.float64), np.asarray(boundary, bool), edges, faces)


def view_of_part(part: Part) -> View:
    """An upload solved for placing (its part: the vertices, areas and boundary the spectrum was
    solved with) as a view."""
    return view_of(part.points, part.mass, part.boundary, part.faces)


def fused_spectrum(
    views: list[View], k: int, places: list[np.ndarray] | None = None, inside: InsideRule | None = None
) -> np.ndarray:
    """The first ``k`` eigenvalues of the views' union (:func:`fused_cloud`): on its glued
    triangles where every view is a mesh, else as an uploaded point cloud is solved; Dirichlet on
    its boundary, or closed where none is left. With ``places`` (each view's points' places on
    the template) and an ``inside`` rule, the boundary points it finds inside the union are freed
    first, where it is made of more than one view (one view's boundary is what was seen: U(A) = A)
    and has a boundary to free (the rule's body fit is the costliest step)."""
    cloud = fused_cloud(views)
    if inside is not None and places is not None and cloud.views > 1 and cloud.boundary.any():
        cloud = cloud.freed(inside(views, places, cloud))
    if cloud.faces is not None:
        return glued_spectrum(cloud.points, cloud.faces, cloud.boundary, k)
    closed = not cloud.boundary.any()
    # Centred: robust-laplacian's point-cloud Laplacian drifts with the distance from the origin
    # (a unit sphere's λ₁ comes out low far from it), and a session's frame is wherever its scanner put it.
    centred = cloud.points - cloud.points.mean(axis=0)
    shape = PointCloud(centred, None if closed else cloud.boundary)
    return np.asarray(cloud_spectrum(shape, SpectrumOptions(k=k, closed=closed)).eigenvalues)
