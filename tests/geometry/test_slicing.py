"""Spectra solved in slices against the dense generalized eigenproblem, and slices that disagree."""

import numpy as np
import pytest
import scipy.linalg
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from app.geometry.errors import GeometryError
from app.geometry.laplacian import Operators, mesh_operators
from app.geometry.pencil import ShiftedPencil
from app.geometry.slicing import InconsistentSlices, sliced_eigenpairs
from app.geometry.spectrum import SLICED_ABOVE, eigenpairs, eigenvalues
from app.geometry.topology import boundary_vertex_mask
from tests.conftest import bumpy_patch, sphere


def dense_spectrum(operators: Operators, fixed: np.ndarray | None, k: int) -> np.ndarray:
    """The first ``k`` eigenvalues of the free vertices' (S, M) by LAPACK, the independent truth."""
    free = np.ones(operators.mass.shape[0], dtype=bool) if fixed is None else ~fixed
    stiffness = operators.stiffness[free][:, free].toarray()
    mass = operators.mass[free][:, free].toarray()
    return scipy.linalg.eigh(stiffness, mass, eigvals_only=True, subset_by_index=[0, k - 1])


class CountingPencil(ShiftedPencil):
    """A pencil that records the shifts it is factorized at."""

    def __init__(self, *args):
        super().__init__(*args)
        self.shifts: list[float] = []

    def factor(self, shift, reuse=None):
        self.shifts.append(shift)
        return super().factor(shift, reuse)


@pytest.fixture(scope="module")
def closed_sphere() -> tuple[Operators, np.ndarray]:
    """sphere(4) (2 562 vertices), whose eigenvalues come in tight clusters of 2l + 1."""
    surface = sphere(4)
    operators = mesh_operators(surface.vertices, surface.faces)
    return operators, dense_spectrum(operators, None, 100)


@pytest.mark.parametrize("size", [7, 12, 30])
def test_clusters_cut_by_the_slices_come_out_whole(size, closed_sphere):
    """Slice edges fall inside the sphere's clusters (9 at l = 2 … 19 at l = 9, split by the
    discretization into sub-clusters 1e-4 apart): every member is found once, in order."""
    operators, truth = closed_sphere
    pencil = CountingPencil(operators, None)
    values = sliced_eigenpairs(pencil, 100, size)[0]
    assert len(pencil.shifts) >= 3
    np.testing.assert_allclose(values, truth, rtol=1e-8, atol=1e-10 * truth[-1])


def test_a_dirichlet_patch_in_slices_matches_the_dense_solve(patch):
    operators = mesh_operators(patch.vertices, patch.faces)
    fixed = boundary_vertex_mask(patch.faces, len(patch.vertices))
    pencil = CountingPencil(operators, fixed)
    values = sliced_eigenpairs(pencil, 90, 20)[0]
    assert len(pencil.shifts) >= 3
    np.testing.assert_allclose(values, dense_spectrum(operators, fixed, 90), rtol=1e-8)


def test_the_service_path_slices_beyond_the_slice_size_and_agrees(closed_sphere):
    operators, truth = closed_sphere
    assert SLICED_ABOVE < 100
    np.testing.assert_allclose(eigenvalues(operators, 100), truth, rtol=1e-8, atol=1e-10 * truth[-1])


class DroppingPencil(ShiftedPencil):
    """ARPACK as if it had converged to the wrong set around one interior shift: one eigenvalue
    of that slice goes missing and the next-nearest takes its place."""

    def nearest(self, factor, count, *, vectors=False, restarts=None):
        values, functions = super().nearest(factor, count + 1, vectors=vectors, restarts=restarts)
        if factor.shift > self.lowest_shift:
            return np.delete(values, count // 2 - 1), None
        return values[:count], functions


def test_a_slice_that_missed_an_eigenvalue_is_caught_where_the_slices_overlap(closed_sphere):
    operators, _ = closed_sphere
    with pytest.raises(InconsistentSlices):
        sliced_eigenpairs(DroppingPencil(operators, None), 100, 25)


def test_slices_reaching_the_end_of_a_small_shapes_spectrum_stay_exact():
    """42 vertices, 41 eigenvalues in slices of 16: the last slice's request is capped by the
    pencil's size and the whole discrete spectrum but one comes out, each value once."""
    surface = sphere(1)
    operators = mesh_operators(surface.vertices, surface.faces)
    truth = dense_spectrum(operators, None, 41)
    values = sliced_eigenpairs(ShiftedPencil(operators, None), 41, 16)[0]
    np.testing.assert_allclose(values, truth, rtol=1e-8, atol=1e-10 * truth[-1])


def test_the_service_falls_back_to_one_solve_when_slices_disagree(closed_sphere, monkeypatch):
    operators, truth = closed_sphere
    monkeypatch.setattr("app.geometry.spectrum.ShiftedPencil", DroppingPencil)
    np.testing.assert_allclose(eigenvalues(operators, 100), truth, rtol=1e-8, atol=1e-10 * truth[-1])


class LandingPencil(ShiftedPencil):
    """Every interior shift moved onto the nearest true eigenvalue, as if its placement had
    landed there: the count of eigenvalues below it is then a pivot's sign at rounding level."""

    def __init__(self, operators, fixed, truth):
        super().__init__(operators, fixed)
        self.truth = truth

    def factor(self, shift, reuse=None):
        if shift > self.lowest_shift:
            shift = float(self.truth[np.abs(self.truth - shift).argmin()])
        return super().factor(shift, reuse)


def test_a_shift_on_an_eigenvalue_is_refused_not_trusted(patch):
    operators = mesh_operators(patch.vertices, patch.faces)
    fixed = boundary_vertex_mask(patch.faces, len(patch.vertices))
    truth = dense_spectrum(operators, fixed, 120)
    with pytest.raises(InconsistentSlices, match="lies on an eigenvalue|broke down"):
        sliced_eigenpairs(LandingPencil(operators, fixed, truth), 90, 20)


@settings(max_examples=25, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(
    st.integers(0, 10_000),
    st.sampled_from([0.0, 0.01, 0.3, 1.0]),
    st.integers(0, 40),
    st.integers(SLICED_ABOVE + 1, 160),
)
def test_on_any_distorted_patch_slices_agree_with_one_solve(seed, jitter, collapsed, k):
    """Vertices jittered by up to an edge length (slivers, folds) and collapsed onto a neighbour
    (zero-area triangles): the service's sliced spectrum equals one ARPACK solve's, or both fail."""
    rng = np.random.default_rng(seed)
    mesh = bumpy_patch(seed % 7)
    edge = np.linalg.norm(mesh.vertices[mesh.faces[:, 0]] - mesh.vertices[mesh.faces[:, 1]], axis=1).mean()
    vertices = mesh.vertices + jitter * edge * rng.standard_normal(mesh.vertices.shape)
    for face in rng.choice(len(mesh.faces), collapsed, replace=False):
        a, b = mesh.faces[face, :2]
        vertices[a] = vertices[b]
    try:
        operators = mesh_operators(vertices, mesh.faces)
        fixed = boundary_vertex_mask(mesh.faces, len(vertices))
        one_solve = eigenpairs(operators, k, fixed)[0]
    except GeometryError:
        with pytest.raises(GeometryError):
            eigenvalues(mesh_operators(vertices, mesh.faces), k, fixed)
        return
    sliced = eigenvalues(operators, k, fixed)
    np.testing.assert_allclose(sliced, one_solve, rtol=1e-8, atol=1e-10 * one_solve[-1])


def assert_eigenbasis(operators: Operators, fixed: np.ndarray | None, values: np.ndarray, functions: np.ndarray):
    """``functions`` are M-orthonormal eigenfunctions of the free vertices' (S, M) for ``values``:
    orthonormal to 1e-8, each residual ‖S x − λ M x‖ tiny beside ‖λ M x‖."""
    free = np.ones(operators.mass.shape[0], dtype=bool) if fixed is None else ~fixed
    stiffness = operators.stiffness[free][:, free]
    mass = operators.mass.diagonal()[free]
    gram = functions.T @ (mass[:, None] * functions)
    assert np.abs(gram - np.eye(len(values))).max() < 1e-8
    residual = stiffness @ functions - values * (mass[:, None] * functions)
    scale = np.linalg.norm(values[-1] * mass[:, None] * functions, axis=0)
    assert (np.linalg.norm(residual, axis=0) <= 1e-7 * scale).all()


@pytest.mark.parametrize("size", [7, 12, 30])
def test_eigenfunctions_of_clusters_cut_by_the_slices_are_an_eigenbasis_or_refused(size, closed_sphere):
    """The sphere's clusters of 2l + 1 cut by slice edges, each slice's solve returning directions
    of the cut eigenspace: the joined basis is M-orthonormal and made of eigenfunctions, or, where
    two solves returned one direction twice (slices of 7 cut a cluster of 17 where no gap helps),
    refused, and the service solves in one piece."""
    operators, truth = closed_sphere
    try:
        values, functions = sliced_eigenpairs(ShiftedPencil(operators, None), 100, size, vectors=True)
    except InconsistentSlices:
        assert size == 7
        values, functions = eigenpairs(operators, 100, vectors=True)
    np.testing.assert_allclose(values, truth, rtol=1e-8, atol=1e-10 * truth[-1])
    assert_eigenbasis(operators, None, values, functions)


def test_the_service_gives_a_dirichlet_patchs_eigenbasis_in_slices_as_one_solve_does(patch):
    """Beyond SLICED_ABOVE the eigenfunctions come in slices: on a patch without repeated
    eigenvalues each is one solve's own, up to its sign."""
    operators = mesh_operators(patch.vertices, patch.faces)
    fixed = boundary_vertex_mask(patch.faces, len(patch.vertices))
    k = SLICED_ABOVE + 26
    values, functions = eigenpairs(operators, k, fixed, vectors=True)
    np.testing.assert_allclose(values, dense_spectrum(operators, fixed, k), rtol=1e-8)
    assert_eigenbasis(operators, fixed, values, functions)
    pencil = ShiftedPencil(operators, fixed)
    _, one_solve = pencil.nearest(pencil.factor(pencil.lowest_shift), k, vectors=True)
    mass = operators.mass.diagonal()[~fixed]
    alignment = np.abs(np.sum(one_solve * mass[:, None] * functions, axis=0))
    np.testing.assert_allclose(alignment, 1.0, atol=1e-6)
