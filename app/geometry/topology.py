"""Combinatorial helpers on triangle meshes: edges, boundary, components, pin-hole filling."""

import numpy as np
import scipy.sparse as sp
from scipy.sparse.csgraph import connected_components


def row_sums(rows: np.ndarray) -> np.ndarray:
    """(m,) the sum of each row of an (m, 3) array, added left to right as ``sum(axis=1)`` adds
    them (the same bits), column by column: NumPy reduces a short axis one row at a time, an
    order of magnitude slower on a mesh's (m, 3) arrays."""
    return rows[:, 0] + rows[:, 1] + rows[:, 2]


def face_areas(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area of each triangle, (m,), in the squared units of ``vertices``: half the norm of the
    cross product of two edges, computed column by column (see :func:`row_sums`)."""
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    u, v = b - a, c - a
    cross = np.column_stack(
        [
            u[:, 1] * v[:, 2] - u[:, 2] * v[:, 1],
            u[:, 2] * v[:, 0] - u[:, 0] * v[:, 2],
            u[:, 0] * v[:, 1] - u[:, 1] * v[:, 0],
        ]
    )
    return 0.5 * np.sqrt(row_sums(cross * cross))


def half_edges(faces: np.ndarray) -> np.ndarray:
    """Directed edges (3m, 2) in face order: all first edges, then all second, then all third."""
    return np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])


def edge_face_counts(half: np.ndarray) -> np.ndarray:
    """For each half-edge, how many faces share its undirected edge (1 = boundary)."""
    low, high = np.minimum(half[:, 0], half[:, 1]), np.maximum(half[:, 0], half[:, 1])
    # A sparse matrix with a one per half-edge at (low, high) sums them per edge on its way to
    # CSR (a bucket pass by row, then a sort within each short row); each half-edge then reads
    # its edge's sum back. A global argsort of one key per edge took 2-3x longer.
    n = int(high.max()) + 1
    counts = sp.csr_matrix((np.ones(len(low), dtype=np.int64), (low, high)), shape=(n, n))
    return np.asarray(counts[low, high]).reshape(-1)


def boundary_half_edges(faces: np.ndarray) -> np.ndarray:
    """Directed edges (h, 2) that belong to exactly one face, oriented as in that face."""
    half = half_edges(faces)
    return half[edge_face_counts(half) == 1]


def boundary_vertex_mask(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """True for vertices on an edge that only one face uses (the Dirichlet boundary)."""
    return vertices_of(boundary_half_edges(faces), n_vertices)


def vertices_of(edges: np.ndarray, n_vertices: int) -> np.ndarray:
    """True for the vertices that ``edges`` (h, 2) touch."""
    mask = np.zeros(n_vertices, dtype=bool)
    mask[edges.reshape(-1)] = True
    return mask


def component_areas(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m,) the connected piece each face belongs to (pieces joined through shared vertices,
    numbered from 0) and (pieces,) each piece's area."""
    n = len(vertices)
    rows = np.repeat(faces[:, 0], 2)
    cols = faces[:, 1:].reshape(-1)
    graph = sp.coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n))
    _, labels = connected_components(graph, directed=False)
    face_labels = np.unique(labels[faces[:, 0]], return_inverse=True)[1]
    return face_labels, np.bincount(face_labels, weights=face_areas(vertices, faces))


def largest_component(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, int]:
    """Faces of the largest connected component by area, and how many others were dropped.

    Components are joined through shared vertices; area, not vertex count, decides, because a
    scan's dense fragment can out-count a coarser main surface.
    """
    face_labels, area = component_areas(vertices, faces)
    if len(area) == 1:
        return faces, 0
    return faces[face_labels == int(np.argmax(area))], len(area) - 1


def referenced(faces: np.ndarray, n_vertices: int) -> np.ndarray:
    """True for the vertices some face uses: the ones :func:`drop_unreferenced` keeps, in order."""
    used = np.zeros(n_vertices, dtype=bool)
    used[faces.reshape(-1)] = True
    return used


def drop_unreferenced(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Remove vertices no face uses (they would give empty rows in the mass matrix)."""
    used = referenced(faces, len(vertices))
    if used.all():
        return vertices, faces
    return vertices[used], (np.cumsum(used) - 1)[faces]


def boundary_loops(half: np.ndarray) -> list[np.ndarray]:
    """Closed loops as vertex sequences along boundary half-edges (from :func:`boundary_half_edges`).

    A loop is traced along its edges whatever way each points, and runs the way most of them
    do: faces wound inconsistently (which the Laplacian does not mind) leave a hole's edges
    pointing both ways, and the hole is still one. Loops through a pinched vertex (more than two
    boundary edges) are ambiguous and left out, so callers never modify a boundary they cannot
    trace unambiguously.
    """
    ends, counts = np.unique(half, return_counts=True)
    pinched = set(ends[counts != 2].tolist())
    neighbours: dict[int, list[int]] = {}
    for a, b in half.tolist():
        if a not in pinched and b not in pinched:
            neighbours.setdefault(a, []).append(b)
            neighbours.setdefault(b, []).append(a)
    directed = set(map(tuple, half.tolist()))
    loops, visited = [], set()
    for start in half[:, 0].tolist():
        if start in visited or start not in neighbours:
            continue
        loop = _traced(start, neighbours, directed, visited)
        if loop is not None:
            loops.append(np.array(loop, dtype=np.int64))
    return loops


def _traced(start: int, neighbours: dict[int, list[int]], directed: set, visited: set) -> list[int] | None:
    """The loop through ``start``, first along the edge its face leaves it by, the way most of
    its edges point; None when the walk does not come back to ``start``."""
    first = next((b for b in neighbours[start] if (start, b) in directed), neighbours[start][0])
    loop, previous, current = [start], start, first
    visited.add(start)
    while current != start and current not in visited:
        visited.add(current)
        loop.append(current)
        ways = neighbours.get(current, [])
        if len(ways) != 2:  # an edge of it runs to a pinched vertex: not a loop to trace
            return None
        previous, current = current, (ways[1] if ways[0] == previous else ways[0])
    if current != start or len(loop) < 3:
        return None
    along = sum((u, v) in directed for u, v in zip(loop, loop[1:] + loop[:1], strict=True))
    return loop if 2 * along >= len(loop) else loop[::-1]


def cap_faces(loop: np.ndarray, centre: int) -> np.ndarray:
    """Fan of triangles closing a boundary ``loop`` (from :func:`boundary_loops`) at vertex ``centre``.

    A boundary half-edge a→b lies in a face ordered a→b; each cap face uses b→a, so the capped
    surface stays consistently oriented.
    """
    return np.column_stack([np.roll(loop, -1), loop, np.full(len(loop), centre)])


def fill_small_holes(
    vertices: np.ndarray,
    faces: np.ndarray,
    boundary: np.ndarray,
    max_edges: int,
    max_relative_perimeter: float = 0.2,
) -> tuple[np.ndarray, np.ndarray, int]:
    """Cap short boundary loops (scanner pin-holes) with a centroid fan.

    Every boundary loop becomes a Dirichlet boundary, so a missing triangle or two would inflate
    the spectrum far beyond what the shape warrants. A loop is a pin-hole when it has at most
    ``max_edges`` edges *and* its perimeter is under ``max_relative_perimeter`` times the square
    root of the surface area: the second test keeps a coarse but genuine partial surface (a
    hexagonal patch) from being closed up. ``boundary`` holds the mesh's boundary half-edges
    (from :func:`boundary_half_edges`): the caller needs them again, so they are found once.

    Returns the new vertices, the new faces and the number of holes filled.
    """
    short = [loop for loop in boundary_loops(boundary) if len(loop) <= max_edges] if max_edges >= 3 else []
    if not short:
        return vertices, faces, 0
    scale = np.sqrt(face_areas(vertices, faces).sum())
    new_vertices, new_faces = [vertices], [faces]
    next_index = len(vertices)
    filled = 0
    for loop in short:
        ring = vertices[loop]
        perimeter = np.linalg.norm(ring - np.roll(ring, -1, axis=0), axis=1).sum()
        if perimeter > max_relative_perimeter * scale:
            continue
        new_vertices.append(ring.mean(axis=0, keepdims=True))
        new_faces.append(cap_faces(loop, next_index))
        next_index += 1
        filled += 1
    return np.concatenate(new_vertices), np.concatenate(new_faces), filled
