"""Stiffness and lumped-mass matrices: the one Laplacian used everywhere.

Meshes get the intrinsic-Delaunay cotangent Laplacian of robust-laplacian: on poor or
re-meshed triangulations it stays far closer to the fine mesh's spectrum than the plain
cotangent matrix. Its edge flips and mollification change nothing on a mesh that is already
intrinsic Delaunay with well-shaped triangles, and they cost ~4x the plain assembly, so such
meshes are assembled directly here; the result is the same matrix (tested).
"""

from typing import NamedTuple

import numpy as np
import robust_laplacian
import scipy.sparse as sp

from app.geometry.topology import edge_face_counts, face_areas, half_edges

# robust-laplacian's defaults, restated so the fast path tests the same condition.
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
    cotangents = _corner_cotangents(vertices, faces)
    if cotangents is not None and _is_intrinsic_delaunay(faces, cotangents, len(vertices)):
        return _cotangent_operators(vertices, faces, cotangents)
    stiffness, mass = robust_laplacian.mesh_laplacian(
        np.ascontiguousarray(vertices, dtype=np.float64),
        np.ascontiguousarray(faces, dtype=np.int64),
        mollify_factor=MOLLIFY_FACTOR,
    )
    return Operators(stiffness.tocsr(), mass.tocsr())


def point_cloud_operators(points: np.ndarray) -> Operators:
    """Point-cloud Laplacian of robust-laplacian (tufted local Delaunay triangulations)."""
    stiffness, mass = robust_laplacian.point_cloud_laplacian(
        np.ascontiguousarray(points, dtype=np.float64),
        mollify_factor=MOLLIFY_FACTOR,
        n_neighbors=POINT_CLOUD_NEIGHBOURS,
    )
    return Operators(stiffness.tocsr(), mass.tocsr())


def _corner_cotangents(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray | None:
    """Cotangent at each corner (m, 3) from edge lengths, or None if a triangle needs mollifying.

    robust-laplacian lengthens every edge when some triangle's inequality slack falls below
    ``MOLLIFY_FACTOR`` times the mean edge length; we only take the fast path when it would not.
    """
    # Edge opposite corner i runs between the other two corners.
    lengths = np.stack(
        [np.linalg.norm(vertices[faces[:, (i + 1) % 3]] - vertices[faces[:, (i + 2) % 3]], axis=1) for i in range(3)],
        axis=1,
    )
    slack = lengths.sum(axis=1, keepdims=True) - 2 * lengths
    if slack.min() <= 2 * MOLLIFY_FACTOR * lengths.mean():
        return None
    squared = lengths**2
    # Heron's formula in the product form, as robust-laplacian computes areas from lengths.
    s = lengths.sum(axis=1) / 2
    area = np.sqrt(s * (s - lengths[:, 0]) * (s - lengths[:, 1]) * (s - lengths[:, 2]))
    return (squared.sum(axis=1, keepdims=True) - 2 * squared) / (4 * area[:, None])


def _edge_weights(faces: np.ndarray, cotangents: np.ndarray, n: int) -> sp.csr_matrix:
    """Symmetric matrix of cotangent weights w_ij = (cot α + cot β) / 2 over each edge."""
    rows = np.concatenate([faces[:, (i + 1) % 3] for i in range(3)])
    cols = np.concatenate([faces[:, (i + 2) % 3] for i in range(3)])
    half = np.concatenate([cotangents[:, i] for i in range(3)]) / 2
    weights = sp.coo_matrix((half, (rows, cols)), shape=(n, n)).tocsr()
    return weights + weights.T


def _is_intrinsic_delaunay(faces: np.ndarray, cotangents: np.ndarray, n: int) -> bool:
    """Every edge has non-negative cotangent weight, and no edge has three or more faces.

    A boundary edge counts too: robust-laplacian works on the tufted cover, where a boundary
    edge sees its one opposite angle twice and is flipped when that angle is obtuse.
    """
    if edge_face_counts(half_edges(faces)).max() > 2:
        return False
    weights = _edge_weights(faces, cotangents, n)
    return bool(weights.data.min() >= -1e-12)


def _cotangent_operators(vertices: np.ndarray, faces: np.ndarray, cotangents: np.ndarray) -> Operators:
    n = len(vertices)
    weights = _edge_weights(faces, cotangents, n)
    stiffness = sp.diags(np.asarray(weights.sum(axis=1)).ravel()) - weights
    thirds = np.repeat(face_areas(vertices, faces) / 3, 3)
    lumped = np.bincount(faces.reshape(-1), weights=thirds, minlength=n)
    return Operators(stiffness.tocsr(), sp.diags(lumped).tocsr())
