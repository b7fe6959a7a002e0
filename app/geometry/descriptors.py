"""What the correspondence network reads of one part: its own eigenbasis, mass, features and
gradient stencils, computed by the engine that computes its spectrum.

Nothing here depends on the file's frame, and little on the body's pose: the eigenbasis is
the part's free-boundary (Neumann) Laplacian's (its low frequencies are where the network
diffuses features), the features are the heat kernel signature of that basis, made
dimensionless (4πt·HKS(x, t) → 1 on a flat patch as t → 0) and logged, the signed mean
curvature with the normal outward, and a flag for the part's boundary (where a scan stops, not
where the body does); the stencils take gradients in each vertex's tangent plane with the
normal turned outward (:mod:`app.geometry.tangent`). Units are metres, as for every spectrum.

The mean curvature is the one input that is not intrinsic, and it is there because a camera
sees half of a limb: a half-cylinder is intrinsically a flat strip, so nothing intrinsic tells a
forearm's view from a patch of the back, where its bend (1/2r: ~12/m on an arm, ~5/m on the
trunk) does at once. It is unchanged by the file's frame and, away from the joints, by the pose.
"""

from dataclasses import dataclass, replace

import numpy as np

from app.contract import CORRESPONDENCE_BASIS, CORRESPONDENCE_INPUTS, HKS_TIMES
from app.geometry.laplacian import Operators, mesh_operators, point_cloud_operators
from app.geometry.spectrum import eigenpairs
from app.geometry.tangent import (
    GradientStencil,
    cloud_neighbours,
    cloud_normals,
    gradient_stencil,
    mesh_neighbours,
    outward_faces,
    vertex_normals,
)
from app.geometry.topology import boundary_vertex_mask

FEATURES = len(HKS_TIMES) + 2  # the HKS at each time, the mean curvature, the boundary flag
BEND_COLUMN, BOUNDARY_COLUMN = FEATURES - 2, FEATURES - 1
CURVATURE_SCALE_M = 0.05  # mean curvature read as asinh(H · 5 cm): ~linear up to a wrist's bend, a finger's ~2


@dataclass(frozen=True)
class PartInputs:
    """The correspondence graph's inputs for one part of n vertices (see app.contract)."""

    features: np.ndarray  # (n, FEATURES) float32
    mass: np.ndarray  # (n,) float32, m²
    basis: np.ndarray  # (n, k) float32, M-orthonormal
    eigenvalues: np.ndarray  # (k,) float32, 1/m²
    stencil: GradientStencil
    points: np.ndarray | None = None  # (n, 3) where they were computed, metres (to show the part by)
    faces: np.ndarray | None = None  # (m, 3) a mesh's outward-wound faces; None for a point cloud

    @property
    def vertices(self) -> int:
        return len(self.mass)

    @property
    def boundary(self) -> np.ndarray:
        """(n,) bool: the part's boundary vertices (the features' last column)."""
        return self.features[:, BOUNDARY_COLUMN] > 0

    def feeds(self) -> dict[str, np.ndarray]:
        """The graph's inputs by their contract names."""
        stencil = self.stencil
        values = (self.features, self.mass, self.basis, self.eigenvalues, stencil.neighbours, stencil.weights)
        return dict(zip(CORRESPONDENCE_INPUTS, values, strict=True))


def mesh_inputs(
    vertices: np.ndarray, faces: np.ndarray, k: int = CORRESPONDENCE_BASIS, operators: Operators | None = None
) -> PartInputs:
    """Inputs of a prepared mesh (``app.geometry.validate.prepare_mesh``), in metres;
    ``operators``: its Laplacian when the spectrum's solve already built it (winding does not
    change it)."""
    operators = operators or mesh_operators(vertices, faces)
    faces = outward_faces(vertices, faces, operators.stiffness)
    normals = vertex_normals(vertices, faces)
    stencil = gradient_stencil(vertices, normals, mesh_neighbours(faces, len(vertices), vertices))
    curvature = mean_curvature(vertices, normals, operators)
    inputs = _inputs(operators, curvature, boundary_vertex_mask(faces, len(vertices)), stencil, k)
    return replace(inputs, points=vertices, faces=faces)


def cloud_inputs(
    points: np.ndarray, boundary: np.ndarray | None, k: int = CORRESPONDENCE_BASIS, operators: Operators | None = None
) -> PartInputs:
    """Inputs of a prepared point cloud, in metres; ``boundary`` flags its boundary points;
    ``operators``: its Laplacian when the spectrum's solve already built it."""
    operators = operators or point_cloud_operators(points)
    neighbours = cloud_neighbours(points)
    normals = cloud_normals(points, neighbours, operators.stiffness)
    stencil = gradient_stencil(points, normals, neighbours)
    flags = np.zeros(len(points), bool) if boundary is None else boundary
    curvature = mean_curvature(points, normals, operators)
    return replace(_inputs(operators, curvature, flags, stencil, k), points=points)


def _inputs(
    operators: Operators, curvature: np.ndarray, boundary: np.ndarray, stencil: GradientStencil, k: int
) -> PartInputs:
    k = min(k, operators.mass.shape[0] - 1)
    values, basis = eigenpairs(operators, k, None, vectors=True)
    values = np.maximum(values, 0.0)
    bend = np.arcsinh(curvature * CURVATURE_SCALE_M)
    features = np.column_stack([heat_signature(values, basis), bend, boundary.astype(np.float64)])
    return PartInputs(
        features.astype(np.float32),
        operators.mass.diagonal().astype(np.float32),
        basis.astype(np.float32),
        values.astype(np.float32),
        stencil,
    )


def magnified(inputs: PartInputs, scale: float) -> PartInputs:
    """``inputs`` as the same part ``scale`` times larger gives them, without a new solve: the
    eigenvalues go as 1/scale², the M-orthonormal basis as 1/scale, the mass as scale², the mean
    curvature and the gradient weights as 1/scale, and the heat kernel signature is re-read at
    the same times (the placing reads a child's part as an adult-sized one:
    :class:`app.inference.correspondence.PlacingGraph`)."""
    values = inputs.eigenvalues.astype(np.float64) / scale**2
    basis = inputs.basis.astype(np.float64) / scale
    bend = np.arcsinh(np.sinh(inputs.features[:, BEND_COLUMN].astype(np.float64)) / scale)  # asinh(H/scale · 5 cm)
    features = np.column_stack([heat_signature(values, basis), bend, inputs.features[:, BOUNDARY_COLUMN]])
    stencil = GradientStencil(inputs.stencil.neighbours, (inputs.stencil.weights / scale).astype(np.float32))
    return replace(
        inputs,
        features=features.astype(np.float32),
        mass=(inputs.mass.astype(np.float64) * scale**2).astype(np.float32),
        basis=basis.astype(np.float32),
        eigenvalues=values.astype(np.float32),
        stencil=stencil,
        points=None if inputs.points is None else inputs.points * scale,
    )


def mean_curvature(points: np.ndarray, normals: np.ndarray, operators: Operators) -> np.ndarray:
    """(n,) signed mean curvature H (1/m) at each point, positive where the surface bends away
    from its ``normals``: S·X = M·2H·n for the positive semi-definite stiffness, read along the
    normal (at a boundary point, where the ring is cut, what remains of it)."""
    mass = operators.mass.diagonal()
    bend = np.einsum("ij,ij->i", normals, operators.stiffness @ points)
    return np.divide(bend, 2.0 * mass, out=np.zeros_like(bend), where=mass > 0)


def heat_signature(values: np.ndarray, basis: np.ndarray) -> np.ndarray:
    """(n, len(HKS_TIMES)) log(4πt · HKS(x, t)) of the truncated eigenbasis: dimensionless,
    ~0 where the surface is flat at scale √t, lower on small or curved regions. Times below
    ~3/λ_k are cut short by the truncation (on a whole body, the first three): they then read
    k/area, the part's size, which is information too."""
    heat = (basis**2) @ np.exp(-np.outer(values, HKS_TIMES))  # (n, times), 1/m²
    return np.log(np.maximum(4 * np.pi * HKS_TIMES * heat, 1e-6))


@dataclass(frozen=True)
class Places:
    """What the correspondence graph answered for one part (app.inference.correspondence runs it,
    in the solver worker that computed its inputs)."""

    position: np.ndarray  # (n, 3) float32, rest-pose template coordinates, metres
    confidence: np.ndarray  # (n,) float32
    graph_ms: float
    magnification: float = 1.0  # how much larger the graph read the part: what placed it surest
