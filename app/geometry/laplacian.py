"""Stiffness and lumped-mass matrices: the one Laplacian used everywhere.

Meshes get the intrinsic-Delaunay cotangent Laplacian of robust-laplacian: on poor or
re-meshed triangulations it stays far closer to the fine mesh's spectrum than the plain
cotangent matrix. For a consistently oriented manifold mesh whose triangles need no
mollification, :mod:`app.geometry.intrinsic` computes the same matrices several times faster
(tested against robust-laplacian); everything else goes to robust-laplacian itself.
"""

from typing import NamedTuple

import numpy as np
import robust_laplacian
import scipy.sparse as sp

from app.geometry.errors import InvalidGeometry, library_reason
from app.geometry.intrinsic import intrinsic_delaunay_operators

# robust-laplacian's defaults, restated so the fast path refuses exactly what it would mollify.
MOLLIFY_FACTOR = 1e-5
POINT_CLOUD_NEIGHBOURS = 30


class Operators(NamedTuple):
    """``stiffness`` S (n, n) positive semidefinite, ``mass`` M (n, n) diagonal, both CSR."""

    stiffness: sp.csr_matrix
    mass: sp.csr_matrix


def mesh_operators(vertices: np.ndarray, faces: np.ndarray) -> Operators:
    """Intrinsic-Delaunay cotangent stiffness and lumped mass of a triangle mesh.

    Parameters
    ----------
    vertices : (n, 3) float array, metres
    faces : (m, 3) int array

    Returns
    -------
    Operators
        S in dimensionless units, M in m²; the generalized eigenvalues of (S, M) are in 1/m².
    """
    fast = intrinsic_delaunay_operators(vertices, faces, MOLLIFY_FACTOR)
    if fast is not None:
        return Operators(*fast)
    try:
        stiffness, mass = robust_laplacian.mesh_laplacian(
            np.ascontiguousarray(vertices, dtype=np.float64),
            np.ascontiguousarray(faces, dtype=np.int64),
            mollify_factor=MOLLIFY_FACTOR,
        )
    except RuntimeError as exc:  # the C++ core reports unusable input this way
        raise InvalidGeometry(f"cannot build a Laplacian for this mesh: {library_reason(exc)}") from exc
    return Operators(stiffness.tocsr(), mass.tocsr())


def point_cloud_operators(points: np.ndarray) -> Operators:
    """Point-cloud Laplacian of robust-laplacian (tufted local Delaunay triangulations)."""
    if len(points) <= POINT_CLOUD_NEIGHBOURS:
        raise InvalidGeometry(f"a point cloud needs more than {POINT_CLOUD_NEIGHBOURS} points, got {len(points)}")
    try:
        stiffness, mass = robust_laplacian.point_cloud_laplacian(
            np.ascontiguousarray(points, dtype=np.float64),
            mollify_factor=MOLLIFY_FACTOR,
            n_neighbors=POINT_CLOUD_NEIGHBOURS,
        )
    except RuntimeError as exc:
        raise InvalidGeometry(f"cannot build a Laplacian for this point cloud: {library_reason(exc)}") from exc
    return Operators(stiffness.tocsr(), mass.tocsr())
