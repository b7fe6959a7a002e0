"""Validate and clean a parsed shape before any solve.

Every check here exists because the eigen-solver would otherwise fail late and obscurely
(NaNs, a singular mass matrix, fewer unknowns than eigenvalues) or answer for the wrong shape
(a stray fragment, a pin-hole acting as a Dirichlet boundary).
"""

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

from app.geometry.errors import InvalidGeometry, MissingBoundary
from app.geometry.shapes import Mesh, PointCloud
from app.geometry.topology import (
    boundary_half_edges,
    drop_unreferenced,
    edge_face_counts,
    face_areas,
    fill_small_holes,
    half_edges,
    largest_component,
    referenced,
    row_sums,
    vertices_of,
)

# A surface edge has one face (boundary) or two; scans show a few non-manifold edges with 3–4.
# robust-laplacian's assembly is quadratic in the faces around one edge (tens of thousands of fins
# on one edge hold a worker for seconds), so an edge shared by more faces than this is refused.
MAX_FACES_PER_EDGE = 16
# Point-cloud clusters (see _largest_cluster): neighbours looked at, and how far past the typical
# neighbour distance a link may reach before two points belong to different clusters.
CLUSTER_NEIGHBOURS = 8
CLUSTER_GAP = 10.0
# A shape smaller than this is no scan of a body part. At this size λ_200 is ~1e12 1/m², far
# inside MAX_EIGENVALUE, so a spectrum the service solves is always one its models can take.
MIN_EXTENT_M = 1e-4
# Weights of no simple ratio (e, π, the golden ratio): distinct scanned vertices, which sit on
# grids and planes of symmetry, share a weighted sum of their coordinates only by a rounding
# coincidence, which costs nothing but the exact sort (see _merge_duplicate_vertices).
_GENERIC = (2.718281828459045, 3.141592653589793, 1.618033988749895)


@dataclass(frozen=True)
class PreparedMesh:
    """A mesh ready for the Laplacian, with what cleaning did to it."""

    mesh: Mesh
    boundary: np.ndarray
    faces_dropped: int
    components_dropped: int
    holes_filled: int
    sources: np.ndarray  # per vertex: its index in the uploaded vertex list, -1 for a pin-hole's centre


@dataclass(frozen=True)
class PreparedCloud:
    """A point cloud ready for the Laplacian; ``boundary`` is None for a closed cloud."""

    cloud: PointCloud
    boundary: np.ndarray | None
    components_dropped: int
    sources: np.ndarray  # per point: its index in the uploaded point list


def require_scan_coordinates(points: np.ndarray) -> None:
    """Refuse NaN or infinite coordinates, coordinates too large to square safely, and a shape
    too small to be a scan (its spectrum would pass what the models can represent: a mesh
    scaled by 1e-30 had λ₁ ≈ 4.5e60)."""
    if points.size == 0:
        raise InvalidGeometry("the shape has no vertices")
    if not np.all(np.isfinite(points)):
        bad = int(np.count_nonzero(~np.isfinite(points).all(axis=1)))
        raise InvalidGeometry(f"{bad} vertices have NaN or infinite coordinates")
    if np.abs(points).max() > 1e12:
        raise InvalidGeometry("coordinates above 1e12 m cannot be a scanned surface")
    if _extent(points) < MIN_EXTENT_M:
        raise InvalidGeometry(
            f"the shape spans {_extent(points):.3g} m, under the {MIN_EXTENT_M:g} m of the smallest scan "
            "(are its units right?)"
        )


def prepare_mesh(mesh: Mesh, *, k: int, max_hole_edges: int, cap_holes: bool = False) -> PreparedMesh:
    """Check, merge, drop repeated and degenerate faces, keep the largest component, fill
    pin-holes (with ``cap_holes``, every boundary loop: a whole-body scan's blind spots, for the
    closed surface's spectrum), and check there is room for k.

    Raises
    ------
    InvalidGeometry
        With a message that says which check failed.
    """
    vertices, faces = mesh.vertices, mesh.faces
    require_scan_coordinates(vertices)
    _require_valid_faces(faces, len(vertices))
    vertices, faces, sources = _merge_duplicate_vertices(vertices, faces)
    given = len(faces)
    faces = surface_faces(faces)
    if len(faces) == 0:
        raise InvalidGeometry("every face repeats a vertex: there is no surface")
    if face_areas(vertices, faces).sum() <= 1e-12 * _extent(vertices) ** 2:
        raise InvalidGeometry("the faces have zero total area")
    faces, dropped = largest_component(vertices, faces)
    sources = sources[referenced(faces, len(vertices))]
    vertices, faces = drop_unreferenced(vertices, faces)
    half = half_edges(faces)
    counts = edge_face_counts(half)
    _require_surface_edges(counts)
    edges = half[counts == 1]
    if cap_holes:  # every traceable loop, whatever its length and perimeter
        vertices, faces, filled = fill_small_holes(vertices, faces, edges, len(edges), np.inf)
    else:
        vertices, faces, filled = fill_small_holes(vertices, faces, edges, max_hole_edges)
    sources = np.r_[sources, np.full(len(vertices) - len(sources), -1)]
    boundary = vertices_of(boundary_half_edges(faces) if filled else edges, len(vertices))
    _require_room_for(k, int(np.count_nonzero(~boundary)))
    return PreparedMesh(Mesh(vertices, faces), boundary, given - len(faces), dropped, filled, sources)


def prepare_cloud(cloud: PointCloud, *, k: int, closed: bool, boundary_indices: list[int] | None) -> PreparedCloud:
    """Check a point cloud, keep its largest cluster, and settle its boundary: declared closed,
    flagged in the file, or listed.

    Automatic boundary detection is not attempted: angular-gap detectors flag interior points
    wherever two surfaces nearly touch (fingers, armpits), and the spectrum is then far off.
    """
    points = cloud.points
    require_scan_coordinates(points)
    points, first = np.unique(points, axis=0, return_index=True)
    flags = None if cloud.boundary is None else cloud.boundary[first]
    if boundary_indices is not None:
        flags = _mask_from_indices(boundary_indices, len(cloud.points))[first]
    keep, dropped = _largest_cluster(points)
    points, flags, sources = points[keep], None if flags is None else flags[keep], first[keep]
    if closed:
        flags = None
    elif flags is None or not flags.any():
        raise MissingBoundary(
            "a partial point cloud needs its boundary points: flag them with a PLY vertex "
            "property 'boundary' or pass their indices; or declare the cloud closed"
        )
    free = len(points) if flags is None else int(np.count_nonzero(~flags))
    _require_room_for(k, free)
    return PreparedCloud(PointCloud(points, flags), flags, dropped, sources)


def _largest_cluster(points: np.ndarray) -> tuple[np.ndarray, int]:
    """The points of the largest cluster, and how many other clusters were dropped.

    The cloud's analogue of a mesh's largest component: two points are linked when one is
    among the other's nearest neighbours and they are no further apart than CLUSTER_GAP times
    the cloud's typical neighbour distance. A depth camera's flying pixels and a stray far
    point fall out as clusters of their own; kept, one far point gave a partial cloud a
    negative λ₁ and a closed one a second near-zero eigenvalue.
    """
    neighbours = min(CLUSTER_NEIGHBOURS, len(points) - 1)
    if neighbours < 1:
        return np.ones(len(points), dtype=bool), 0
    distances, indices = cKDTree(points).query(points, k=neighbours + 1)
    typical = float(np.median(distances[:, -1]))
    linked = distances[:, 1:] <= CLUSTER_GAP * typical
    rows = np.repeat(np.arange(len(points)), neighbours)[linked.ravel()]
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, indices[:, 1:].ravel()[linked.ravel()])), (len(points),) * 2)
    count, labels = connected_components(graph, directed=False)
    if count == 1:
        return np.ones(len(points), dtype=bool), 0
    return labels == np.bincount(labels).argmax(), count - 1


def _mask_from_indices(indices: list[int], n: int) -> np.ndarray:
    idx = np.asarray(indices, dtype=np.int64).reshape(-1)
    if idx.size and (idx.min() < 0 or idx.max() >= n):
        raise InvalidGeometry(f"boundary indices must lie in [0, {n - 1}]")
    mask = np.zeros(n, dtype=bool)
    mask[idx] = True
    return mask


def _require_valid_faces(faces: np.ndarray, n_vertices: int) -> None:
    if faces.ndim != 2 or faces.shape[1] != 3:
        raise InvalidGeometry("faces must be triangles")
    if faces.min() < 0 or faces.max() >= n_vertices:
        raise InvalidGeometry(f"face indices must lie in [0, {n_vertices - 1}], found {faces.min()}..{faces.max()}")


def _merge_duplicate_vertices(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Merge vertices with identical coordinates (STL stores every triangle on its own); also
    returns, per kept vertex, the index of the uploaded vertex it stands for.

    A mesh without any (the usual case) comes back as it was, in its own vertex order: shown by
    one generic combination of the coordinates, which identical vertices share, taking as many
    values as there are vertices (a sort of one column, several times faster than the
    lexicographic sort of all three that finds the duplicates otherwise, itself faster than
    np.unique over rows).
    """
    combined = np.sort(vertices[:, 0] * _GENERIC[0] + vertices[:, 1] * _GENERIC[1] + vertices[:, 2] * _GENERIC[2])
    if not (combined[1:] == combined[:-1]).any():
        return vertices, faces, np.arange(len(vertices))
    order = np.lexsort(vertices.T[::-1])
    ordered = vertices[order]
    same = ordered[1:] == ordered[:-1]
    repeats = np.r_[False, same[:, 0] & same[:, 1] & same[:, 2]]
    if not repeats.any():
        return vertices, faces, np.arange(len(vertices))
    label = np.empty(len(vertices), dtype=np.int64)
    label[order] = np.cumsum(~repeats) - 1
    return ordered[~repeats], label[faces], order[~repeats]


def _require_surface_edges(counts: np.ndarray) -> None:
    """Refuse an edge shared by more than MAX_FACES_PER_EDGE faces (``counts``: per half-edge)."""
    most = int(counts.max())
    if most > MAX_FACES_PER_EDGE:
        raise InvalidGeometry(
            f"an edge is shared by {most} faces (at most {MAX_FACES_PER_EDGE} are accepted): this is not a surface"
        )


def surface_faces(faces: np.ndarray) -> np.ndarray:
    """The faces that are surface: each triangle once (:func:`distinct_faces`), none that
    repeats a vertex (no area, and a zero row the Laplacian cannot take)."""
    a, b, c = faces.T
    return distinct_faces(faces[(a != b) & (b != c) & (c != a)])


def distinct_faces(faces: np.ndarray) -> np.ndarray:
    """Each triangle once, in the order first given, whatever its orientation or vertex order.

    A repeated face is not more surface: it multiplies its area in the mass matrix (a disk's λ₁
    moves with copies of one face), and robust-laplacian's assembly is quadratic in the copies
    (a hundred thousand of them hold a worker for minutes), so they go before assembly.
    """
    if len(faces) < 2:
        return faces
    low = np.minimum(np.minimum(faces[:, 0], faces[:, 1]), faces[:, 2])
    high = np.maximum(np.maximum(faces[:, 0], faces[:, 1]), faces[:, 2])
    ordered = np.column_stack([low, row_sums(faces) - low - high, high])  # each row sorted
    n = int(ordered.max()) + 1
    if n**3 < 2**63:  # one int64 key per triangle: a sort instead of np.unique over rows (several times slower)
        keys = (ordered[:, 0] * n + ordered[:, 1]) * n + ordered[:, 2]
        ranked = np.sort(keys)
        if not (ranked[1:] == ranked[:-1]).any():
            return faces
        _, first = np.unique(keys, return_index=True)
    else:
        _, first = np.unique(ordered, axis=0, return_index=True)
    return faces[np.sort(first)]


def _extent(points: np.ndarray) -> float:
    return max(float(column.max() - column.min()) for column in points.T)  # by column: see row_sums


def _require_room_for(k: int, free_vertices: int) -> None:
    if free_vertices < k + 1:
        raise InvalidGeometry(f"{free_vertices} interior vertices are too few for {k} eigenvalues (need {k + 1})")
