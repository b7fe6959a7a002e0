"""The spectrum engine against analytic spectra and exact properties of the continuous operator."""

import numpy as np
import pytest
import scipy.linalg
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from app.geometry.errors import SolverFailure
from app.geometry.laplacian import mesh_operators
from app.geometry.pencil import NoConvergence, ShiftedPencil
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from app.geometry.spectrum import MAX_RESTARTS, eigenpairs, eigenvalues, shift_for
from app.geometry.topology import boundary_vertex_mask
from tests.conftest import disk, grid, sphere

# Squared zeros of the Bessel functions J_n: the Dirichlet spectrum of the unit disk.
DISK = [5.7832, 14.682, 14.682, 26.375, 26.375, 30.471, 40.706, 40.706, 49.218, 49.218]
# Dirichlet spectrum of [0, π]²: m² + n² for m, n ≥ 1.
SQUARE = sorted(m * m + n * n for m in range(1, 10) for n in range(1, 10))[:16]
# Closed unit sphere: l(l + 1) with multiplicity 2l + 1.
SPHERE = [d * (d + 1) for d in range(5) for _ in range(2 * d + 1)][:20]


def spectrum_of(mesh: Mesh, k: int = 20) -> np.ndarray:
    return np.array(mesh_spectrum(mesh, SpectrumOptions(k=k, max_hole_edges=0)).eigenvalues)


def test_unit_disk_matches_bessel_zeros():
    values = spectrum_of(disk(rings=30), k=len(DISK))
    np.testing.assert_allclose(values, DISK, rtol=0.01)


def test_square_matches_sum_of_squares():
    values = spectrum_of(grid(np.pi, np.pi, 60, 60), k=len(SQUARE))
    np.testing.assert_allclose(values, SQUARE, rtol=0.01)


def test_closed_sphere_matches_l_l_plus_one():
    report = mesh_spectrum(sphere(4), SpectrumOptions(k=20))
    assert report.boundary == "none"
    values = np.array(report.eigenvalues)
    assert abs(values[0]) < 1e-8
    np.testing.assert_allclose(values[1:], SPHERE[1:], rtol=0.01)


def test_agrees_with_plain_scipy_solve_of_the_same_matrices(patch):
    operators = mesh_operators(patch.vertices, patch.faces)
    fixed = boundary_vertex_mask(patch.faces, len(patch.vertices))
    free = np.flatnonzero(~fixed)
    stiffness = operators.stiffness[free][:, free]
    mass = operators.mass[free][:, free]
    reference = np.sort(sla.eigsh(stiffness, 20, mass, sigma=shift_for(mass))[0])
    np.testing.assert_allclose(eigenvalues(operators, 20, fixed), reference, rtol=1e-8)


@pytest.fixture(scope="module")
def sphere_and_dense_spectrum():
    """sphere(4)'s operators and its first 60 eigenvalues by the dense generalized solver."""
    surface = sphere(4)
    operators = mesh_operators(surface.vertices, surface.faces)
    dense = scipy.linalg.eigh(
        operators.stiffness.toarray(), operators.mass.toarray(), eigvals_only=True, subset_by_index=[0, 59]
    )
    return operators, dense


@pytest.mark.parametrize("k", [20, 60])
def test_a_closed_sphere_with_its_multiplicity_clusters_agrees_with_the_dense_solve(k, sphere_and_dense_spectrum):
    """The discrete sphere's eigenvalues come in tight clusters (λ₁₇…λ₂₀ = 19.8665 four times,
    then 19.8765 five times), where an iteration that stops early takes a member of the next
    cluster for the last one it wants: a plain SciPy shift-invert solve does (its λ₂₀ is
    19.8765). The truth is the dense generalized eigenproblem; λ₁ = 0 is measured against λ_k."""
    operators, dense = sphere_and_dense_spectrum
    truth = dense[:k]
    np.testing.assert_allclose(eigenvalues(operators, k), truth, rtol=1e-8, atol=1e-10 * truth[-1])


def test_any_symmetric_stiffness_layout_gives_the_dense_pencil_spectrum():
    """Duplicate stored entries and vertices without a stored diagonal entry (an isolated vertex
    of the stiffness graph) are what the one-pass assembly of the shifted system must not miss."""
    rng = np.random.default_rng(3)
    n = 40
    tails, heads = rng.integers(0, n - 5, 120), rng.integers(0, n - 5, 120)  # the last 5 isolated
    weights = rng.uniform(0.5, 2.0, 120)
    laplacian = sp.coo_matrix(
        (
            np.r_[-weights, -weights, weights, weights],
            (np.r_[tails, heads, tails, heads], np.r_[heads, tails, tails, heads]),
        ),
        shape=(n, n),
    )
    stiffness = sp.csr_matrix((laplacian.data, (laplacian.row, laplacian.col)), shape=(n, n))
    stiffness.eliminate_zeros()  # loops (tail == head) cancel; their rows keep no diagonal entry
    duplicated = sp.csr_matrix(  # the same matrix, every entry stored as two halves
        (np.repeat(stiffness.data / 2, 2), np.repeat(stiffness.indices, 2), 2 * stiffness.indptr), shape=(n, n)
    )
    assert not duplicated.has_canonical_format
    assert np.count_nonzero(stiffness.diagonal()) < n
    mass = sp.diags(rng.uniform(0.5, 1.5, n)).tocsr()
    fixed = np.zeros(n, bool)
    fixed[[0, 7, n - 1]] = True
    free = np.flatnonzero(~fixed)
    reference = scipy.linalg.eigh(stiffness.toarray()[np.ix_(free, free)], mass.toarray()[np.ix_(free, free)])[0]
    for matrix in (stiffness, duplicated):
        np.testing.assert_allclose(eigenvalues((matrix, mass), 10, fixed), reference[:10], rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(
        eigenvalues((duplicated, mass), 10), scipy.linalg.eigh(stiffness.toarray(), mass.toarray())[0][:10], atol=1e-9
    )


def test_rigid_motion_and_reordering_leave_the_spectrum_unchanged(patch):
    rng = np.random.default_rng(1)
    rotation, _ = np.linalg.qr(rng.standard_normal((3, 3)))
    moved = patch.vertices @ rotation.T + np.array([3.0, -2.0, 0.5])
    order = rng.permutation(len(patch.vertices))
    inverse = np.argsort(order)
    shuffled = Mesh(moved[order], inverse[patch.faces][rng.permutation(len(patch.faces))])
    np.testing.assert_allclose(spectrum_of(shuffled), spectrum_of(patch), rtol=1e-8)


@pytest.mark.parametrize("factor", [0.01, 3.0, 1000.0])
def test_scaling_law(patch, factor):
    scaled = Mesh(patch.vertices * factor, patch.faces)
    np.testing.assert_allclose(spectrum_of(scaled), spectrum_of(patch) / factor**2, rtol=1e-8)


def test_isometric_bending_keeps_the_spectrum():
    flat = grid(np.pi, 1.0, 90, 30)
    angle = flat.vertices[:, 0]  # arc length on the unit circle
    rolled = np.column_stack([np.cos(angle), flat.vertices[:, 1], np.sin(angle)])
    bent = spectrum_of(Mesh(rolled, flat.faces), k=10)
    np.testing.assert_allclose(bent, spectrum_of(flat, k=10), rtol=0.01)


def test_a_subregion_has_larger_dirichlet_eigenvalues():
    whole = disk(rings=20)
    centroids = whole.vertices[whole.faces].mean(axis=1)
    inner = centroids[:, 0] ** 2 + (centroids[:, 1] - 0.2) ** 2 < 0.6**2
    region = Mesh(whole.vertices, whole.faces[inner])
    assert np.all(spectrum_of(whole, k=15) <= spectrum_of(region, k=15))


def test_pin_hole_is_filled_and_the_sphere_stays_closed():
    full = sphere(3)
    holed = Mesh(full.vertices, full.faces[1:])
    report = mesh_spectrum(holed, SpectrumOptions(k=10, max_hole_edges=8))
    assert report.holes_filled == 1
    assert report.boundary == "none"
    np.testing.assert_allclose(report.eigenvalues[1:], spectrum_of(full, k=10)[1:], rtol=0.01)


def test_a_coarse_genuine_boundary_is_not_filled():
    hexagon = disk(rings=4)
    report = mesh_spectrum(hexagon, SpectrumOptions(k=5, max_hole_edges=8))
    assert report.holes_filled == 0
    assert report.boundary == "dirichlet"


def test_largest_component_by_area_is_kept():
    big, small = disk(radius=1.0, rings=15), disk(radius=0.5, rings=25)
    shifted = small.vertices + np.array([5.0, 0.0, 0.0])
    both = Mesh(
        np.concatenate([shifted, big.vertices]),
        np.concatenate([small.faces, big.faces + len(shifted)]),
    )
    report = mesh_spectrum(both, SpectrumOptions(k=8))
    assert report.components_dropped == 1
    np.testing.assert_allclose(report.eigenvalues, spectrum_of(big, k=8), rtol=1e-8)


def test_eigenfunctions_are_mass_orthonormal_and_solve_the_pencil(patch):
    operators = mesh_operators(patch.vertices, patch.faces)
    values, functions = eigenpairs(operators, 8)
    gram = functions.T @ operators.mass @ functions
    np.testing.assert_allclose(gram, np.eye(8), atol=1e-8)
    residual = operators.stiffness @ functions - operators.mass @ functions * values
    assert np.abs(residual).max() < 1e-8 * values.max()


def test_a_solver_breakdown_is_a_solver_failure_not_a_crash(patch):
    """ARPACK cannot build an Arnoldi factorization from a poisoned operator: the caller gets our error."""
    stiffness, mass = mesh_operators(patch.vertices, patch.faces)
    poisoned = stiffness.tolil()
    poisoned[5, 5] = np.nan
    with pytest.raises(SolverFailure, match="eigen-solver failed"):
        eigenvalues((poisoned.tocsr(), mass), 10)


def test_a_factor_moved_to_another_shift_is_that_shifts_factor(patch):
    """Refactored in place (its ordering and analysis kept), a factor solves and counts exactly as
    one built afresh at the new shift: the same solution to the last bit, the same inertia."""
    operators = mesh_operators(patch.vertices, patch.faces)
    pencil = ShiftedPencil(operators, boundary_vertex_mask(patch.faces, len(patch.vertices)))
    truth = eigenvalues(operators, 30, boundary_vertex_mask(patch.faces, len(patch.vertices)))
    shift = float(truth[11] + truth[12]) / 2  # twelve eigenvalues below it
    moved = pencil.factor(pencil.lowest_shift)
    assert moved.below == 0
    assert pencil.factor(shift, reuse=moved) is moved and moved.shift == shift
    fresh = pencil.factor(shift)
    right = np.random.default_rng(0).standard_normal(pencil.size)
    np.testing.assert_array_equal(moved.operator.matvec(right), fresh.operator.matvec(right))
    assert moved.below == fresh.below == 12


def test_a_factor_is_not_moved_onto_another_sparsity(patch):
    """The same shape with its boundary held fixed has fewer unknowns: a new factor, the old one
    left as it was."""
    operators = mesh_operators(patch.vertices, patch.faces)
    factor = ShiftedPencil(operators).factor(-1.0)
    other = ShiftedPencil(operators, boundary_vertex_mask(patch.faces, len(patch.vertices)))
    assert other.factor(-1.0, reuse=factor) is not factor
    assert factor.shift == -1.0


def test_a_strip_whose_spectrum_is_nearly_degenerate_is_refused_not_solved_for_minutes():
    """A 50 m × 4 cm strip three vertices wide: its Dirichlet eigenvalues all lie within 0.01 % of
    (π / 0.04 m)², which ARPACK separates only after hundreds of restarts (a minute of a worker
    for 60 000 vertices); the solve stops at its restart budget and says why."""
    n, length, width = 2000, 50.0, 0.02
    x = np.linspace(0, length, n)
    vertices = np.concatenate([np.column_stack([x, np.full(n, row * width), np.zeros(n)]) for row in range(3)])
    start = np.arange(n - 1)
    faces = []
    for row in range(2):
        row_start = row * n + start
        faces += [np.column_stack([row_start, row_start + 1, row_start + n + 1])]
        faces += [np.column_stack([row_start, row_start + n + 1, row_start + n])]
    with pytest.raises(NoConvergence, match=f"not within {MAX_RESTARTS}"):
        mesh_spectrum(Mesh(vertices, np.concatenate(faces)), SpectrumOptions(k=20))
