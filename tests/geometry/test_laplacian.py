"""Our intrinsic Delaunay flips give robust-laplacian's matrices, and hand over what they can't do."""

import numpy as np
import pytest
import robust_laplacian

from app.geometry.intrinsic import intrinsic_delaunay_operators
from app.geometry.laplacian import MOLLIFY_FACTOR, Operators, mesh_operators
from app.geometry.shapes import Mesh
from app.geometry.spectrum import eigenvalues
from tests.conftest import bumpy_patch, disk, grid, sphere


def sheared_grid(shear: float) -> Mesh:
    """Every cell's diagonal runs along its long axis, facing two obtuse angles."""
    mesh = grid(1.0, 1.0, 20, 20)
    return Mesh(mesh.vertices + np.outer(mesh.vertices[:, 1], [shear, 0.0, 0.0]), mesh.faces)


def bumpy_sphere(noise: float = 1e-3) -> Mesh:
    """A closed surface whose icosphere triangulation is far from Delaunay after stretching.

    Without ``noise`` it keeps mirror symmetries that make some flipped quads exactly
    co-circular.
    """
    mesh = sphere(3)
    v = mesh.vertices * np.array([1.0, 0.4, 2.5])
    v = v * (1 + 0.15 * np.sin(4 * v[:, [0]]) * np.cos(3 * v[:, [2]]))
    return Mesh(v + np.random.default_rng(0).normal(scale=noise, size=v.shape), mesh.faces)


def plain_cotangent_weights(mesh: Mesh) -> np.ndarray:
    """cot α + cot β per edge occurrence, from corner angles, with no flips."""
    v, f = mesh.vertices, mesh.faces
    weights = {}
    for i in range(3):
        a, b, c = v[f[:, i]], v[f[:, (i + 1) % 3]], v[f[:, (i + 2) % 3]]
        u, w = b - a, c - a
        cot = np.einsum("ij,ij->i", u, w) / np.linalg.norm(np.cross(u, w), axis=1)
        for j, k, value in zip(f[:, (i + 1) % 3], f[:, (i + 2) % 3], cot, strict=True):
            key = (min(j, k), max(j, k))
            weights[key] = weights.get(key, 0.0) + value
    return np.array(list(weights.values()))


def robust(mesh: Mesh):
    return robust_laplacian.mesh_laplacian(mesh.vertices, mesh.faces, mollify_factor=MOLLIFY_FACTOR)


@pytest.mark.parametrize(
    "mesh",
    [disk(rings=10), sheared_grid(0.8), sheared_grid(2.5), bumpy_patch(), bumpy_sphere()],
    ids=["delaunay disk", "interior flips", "boundary flips", "random patch", "closed"],
)
def test_flips_reproduce_robust_laplacian(mesh):
    ours = intrinsic_delaunay_operators(mesh.vertices, mesh.faces, MOLLIFY_FACTOR)
    assert ours is not None
    stiffness, mass = robust(mesh)
    assert abs(ours[0] - stiffness).max() < 1e-11 * abs(stiffness).max()
    assert abs(ours[1] - mass).max() < 1e-12 * mass.max()


def test_exact_co_circular_ties_change_the_mass_but_not_the_spectrum():
    # Both diagonals of a co-circular quad are Delaunay; which one a flip order reaches
    # moves lumped mass between its corners. The stiffness and the spectrum stay put.
    mesh = bumpy_sphere(noise=0.0)
    ours = Operators(*intrinsic_delaunay_operators(mesh.vertices, mesh.faces, MOLLIFY_FACTOR))
    stiffness, mass = robust(mesh)
    assert abs(ours.stiffness - stiffness).max() < 1e-11 * abs(stiffness).max()
    theirs = eigenvalues(Operators(stiffness.tocsr(), mass.tocsr()), 20)
    np.testing.assert_allclose(eigenvalues(ours, 20)[1:], theirs[1:], rtol=1e-4)


@pytest.mark.parametrize("mesh", [sheared_grid(0.8), bumpy_sphere()])
def test_those_meshes_are_not_delaunay_to_begin_with(mesh):
    assert plain_cotangent_weights(mesh).min() < -0.1


def test_non_manifold_mesh_falls_back_to_robust_laplacian():
    mesh = disk(rings=6)
    a, b = mesh.faces[0, 0], mesh.faces[0, 1]
    fin = Mesh(
        np.vstack([mesh.vertices, [[0.0, 0.0, 1.0]]]), np.vstack([mesh.faces, [[a, b, len(mesh.vertices)]]])
    )  # a third face on edge a–b
    assert intrinsic_delaunay_operators(fin.vertices, fin.faces, MOLLIFY_FACTOR) is None
    ours = mesh_operators(fin.vertices, fin.faces)
    stiffness, _ = robust(fin)
    assert abs(ours.stiffness - stiffness).max() == 0


def test_needle_triangle_falls_back_to_robust_laplacian():
    v = np.array([[0.0, 0, 0], [1, 0, 0], [0.5, 1e-9, 0], [0.5, -1, 0]])
    f = np.array([[0, 1, 2], [1, 0, 3]])
    assert intrinsic_delaunay_operators(v, f, MOLLIFY_FACTOR) is None
    ours = mesh_operators(v, f)
    stiffness, _ = robust(Mesh(v, f))
    assert abs(ours.stiffness - stiffness).max() == 0
