"""A part as the correspondence graph places it: itself, or, for a mesh above a vertex budget,
a simplified copy of it whose places its own vertices take.

Why: placing costs the part's 64-function eigenbasis and the graph's pass over every vertex,
both growing with the vertices, while the places vary over centimetres, not over a fine mesh's
millimetres. The copy is the mesh's quadric edge collapse (fast-simplification: the collapse
that makes the training's re-meshed parts), each vertex taking the place of the copy's vertex
it collapsed into. On the validation draws of the training people, meshes placed through a copy
of 6 000 vertices kept their region within 0.1 point of their own and a 10 k-vertex part cost
a third less (``docs/decisions/031-meshes-placed-through-a-copy-of-6000-vertices.md``). A point
cloud's copy is a random 8 000 of its points (seeded: one cloud, one copy), each point taking
its nearest kept point's place: 0.0–0.2 point of region lost there, where a voxel grid's lost
1.7; only clouds above it are copied, so that placing a 99 k-point cloud no longer holds a
worker for half a minute. The copy is an
optimization, never a reason to refuse: where it fails the service's own checks, the part is
placed itself. Everything else a client gets (the part's vertices, area, boundary, region) is
the part's own.
"""

from dataclasses import dataclass, replace

import fast_simplification
import numpy as np
from scipy.spatial import cKDTree

from app.geometry.descriptors import PartInputs, Places, cloud_inputs, mesh_inputs
from app.geometry.errors import GeometryError, InvalidGeometry
from app.geometry.laplacian import Operators
from app.geometry.shapes import Mesh
from app.geometry.tangent import outward_faces
from app.geometry.topology import boundary_vertex_mask
from app.geometry.validate import prepare_mesh

PLACED_VERTICES = 6_000  # about the most vertices the graph reads of one mesh (the service's default)
PLACED_POINTS = 8_000  # the most points the graph reads of one point cloud
COPY_SEED = 0


@dataclass(frozen=True)
class Part:
    """An uploaded part ready to be placed: what the graph reads (``inputs``, of the part or of
    its copy) and what the places are answered on (the part's own vertices)."""

    inputs: PartInputs
    points: np.ndarray | None  # (n, 3) the part's vertices, metres (as its inputs carry them)
    faces: np.ndarray | None  # (m, 3) its outward-wound faces; None for a point cloud
    mass: np.ndarray  # (n,) its lumped area at each vertex, m²
    boundary: np.ndarray  # (n,) bool: its boundary vertices
    source: np.ndarray | None = None  # (n,) the copy's vertex each vertex takes its place from; None: no copy

    @classmethod
    def itself(cls, inputs: PartInputs) -> "Part":
        """A part placed on its own vertices: the graph reads its ``inputs``."""
        return cls(inputs, inputs.points, inputs.faces, inputs.mass, inputs.boundary)

    def expand(self, places: Places) -> Places:
        """The graph's places of ``inputs`` as the places of the part's own vertices."""
        if self.source is None:
            return places
        return replace(places, position=places.position[self.source], confidence=places.confidence[self.source])


def mesh_part(vertices: np.ndarray, faces: np.ndarray, operators: Operators, most: int = PLACED_VERTICES) -> Part:
    """A prepared mesh (metres, its Laplacian ``operators``) placed through a copy of about
    ``most`` vertices where it has more."""
    if len(vertices) > most:
        # Collapsed as wound outward and in metres: the collapse depends on winding and scale,
        # not on the frame.
        own = outward_faces(vertices, faces, operators.stiffness)
        try:
            copy, source = _collapsed(vertices, own, most)
            inputs = mesh_inputs(copy.vertices, copy.faces)
        except (GeometryError, ValueError):
            pass  # placed itself below
        else:
            mass = operators.mass.diagonal().astype(np.float32)
            return Part(inputs, vertices, own, mass, boundary_vertex_mask(own, len(vertices)), source)
    return Part.itself(mesh_inputs(vertices, faces, operators=operators))


def cloud_part(points: np.ndarray, boundary: np.ndarray | None, operators: Operators) -> Part:
    """A prepared point cloud (metres, its Laplacian ``operators``; ``boundary`` flags its
    boundary points), placed through a random PLACED_POINTS of its points where it has more."""
    if len(points) > PLACED_POINTS:
        kept = np.sort(np.random.default_rng(COPY_SEED).choice(len(points), PLACED_POINTS, replace=False))
        try:
            inputs = cloud_inputs(points[kept], None if boundary is None else boundary[kept])
        except (GeometryError, ValueError):
            pass  # placed itself below
        else:
            source = cKDTree(points[kept]).query(points)[1]
            flags = np.zeros(len(points), bool) if boundary is None else boundary
            return Part(inputs, points, None, operators.mass.diagonal().astype(np.float32), flags, source)
    return Part.itself(cloud_inputs(points, boundary, operators=operators))


def _collapsed(vertices: np.ndarray, faces: np.ndarray, most: int) -> tuple[Mesh, np.ndarray]:
    """The mesh's quadric edge collapse to about ``most`` vertices, through the service's checks,
    and for each vertex the copy's vertex it collapsed into (or, where the checks dropped that
    one, the copy's nearest). Raises :class:`GeometryError` where the copy fails the checks or
    the collapse's record does not match it."""
    _, _, collapses = fast_simplification.simplify(
        vertices, faces, target_reduction=1 - most / len(vertices), return_collapses=True
    )
    points, triangles, collapsed_into = fast_simplification.replay_simplification(vertices, faces, collapses)
    if collapsed_into.shape != (len(vertices),) or not np.all((collapsed_into >= 0) & (collapsed_into < len(points))):
        raise InvalidGeometry("the collapse's record does not number its copy's vertices")
    prepared = prepare_mesh(
        Mesh(np.asarray(points, np.float64), np.asarray(triangles, np.int64)), k=1, max_hole_edges=0
    )
    kept = prepared.sources >= 0
    renumber = np.full(len(points), -1)
    renumber[prepared.sources[kept]] = np.flatnonzero(kept)
    source = renumber[collapsed_into]
    lost = source < 0
    if lost.any():
        source[lost] = cKDTree(prepared.mesh.vertices).query(vertices[lost])[1]
    return prepared.mesh, source
