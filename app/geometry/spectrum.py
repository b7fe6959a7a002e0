"""Truncated Laplace–Beltrami spectra: the first k eigenvalues of S x = λ M x.

A surface with boundary gets homogeneous Dirichlet conditions (boundary vertices removed from
the system); a closed one the plain spectrum, whose λ₁ = 0. Eigenvalues are in 1/m² when
the shape is in metres.

Speed: M is diagonal, so the pencil is turned into the standard symmetric problem
C = M^-1/2 S M^-1/2 and solved by ARPACK in shift-invert mode. The shifted matrix is
symmetric positive definite, so it gets one sparse LDLᵀ factorization (QDLDL with AMD
ordering) that every ARPACK iteration reuses; SciPy's default path uses a general LU instead.
"""

import numpy as np
import qdldl
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from app.geometry.errors import SolverFailure
from app.geometry.laplacian import Operators

DEFAULT_K = 20
MAX_K = 200
# The largest eigenvalue a spectrum may hold, solved or sent: a shape 0.1 mm across (the
# smallest accepted) has λ_200 ≈ 1e12 1/m². The models run in float32 (max 3.4e38), and a
# value cast past that range came back as null from the union and the localizer.
MAX_EIGENVALUE = 1e15
# Solvers return λ₁ of a closed surface as ±1e-12·λ_k, and ties as tiny inversions.
ORDER_TOLERANCE = 1e-6
# The shift sits below λ₁ = 0 of a closed surface by this fraction of 1/area, i.e. well under
# any eigenvalue of the shape but on its own scale, so the method is scale-equivariant.
RELATIVE_SHIFT = 1e-2
# ARPACK's relative tolerance on the shift-inverted Ritz values; 0 means machine precision.
ARPACK_TOL = 0.0


def shift_for(mass: sp.spmatrix) -> float:
    """The shift σ used for the shape with lumped mass ``mass`` (1/m²)."""
    return _shift(mass.diagonal())


def _shift(lumped_mass: np.ndarray) -> float:
    return -RELATIVE_SHIFT / float(lumped_mass.sum())


def eigenvalues(operators: Operators, k: int, fixed: np.ndarray | None = None) -> np.ndarray:
    """The ``k`` smallest eigenvalues of (S, M), ascending; see :func:`eigenpairs`."""
    return eigenpairs(operators, k, fixed, vectors=False)[0]


def eigenpairs(
    operators: Operators, k: int, fixed: np.ndarray | None = None, *, vectors: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``k`` smallest eigenvalues of (S, M), ascending, with x = 0 on ``fixed`` vertices.

    Parameters
    ----------
    operators : Operators
        Stiffness S and diagonal lumped mass M of the whole shape.
    k : int
        Number of eigenvalues, 1 ≤ k < number of free vertices.
    fixed : (n,) bool array or None
        Dirichlet vertices, removed from the system; None for a closed shape.

    vectors : bool
        Also return the eigenfunctions (the training package needs the template's).

    Returns
    -------
    values : (k,) float64 array, non-decreasing, in the inverse squared units of the shape.
    functions : (n_free, k) array, M-orthonormal, or None without ``vectors``.

    Raises
    ------
    SolverFailure
        When the factorization or ARPACK fails (a pathological shape).
    """
    inverse, sigma, inverse_root = shift_invert(operators, k, fixed)
    n = inverse.shape[0]
    try:
        start = np.random.default_rng(0).standard_normal(n)
        # In shift-invert mode with OPinv given, eigsh reads only the shape and dtype of its
        # first argument: C itself is never multiplied, so it is never assembled.
        result = sla.eigsh(
            inverse,
            k=k,
            sigma=sigma,
            OPinv=inverse,
            which="LM",
            v0=start,
            tol=ARPACK_TOL,
            return_eigenvectors=vectors,
        )
    except (ValueError, sla.ArpackError) as exc:
        raise SolverFailure(f"the eigen-solver failed on this shape: {exc}") from exc
    values, standard_vectors = (result, None) if not vectors else result
    order = np.argsort(values)
    _require_a_spectrum(values[order])
    if standard_vectors is None:
        return values[order], None
    # x = M^-1/2 y turns orthonormal eigenvectors of C into M-orthonormal ones of (S, M).
    return values[order], inverse_root[:, None] * standard_vectors[:, order]


def shift_invert(
    operators: Operators, k: int, fixed: np.ndarray | None = None
) -> tuple[sla.LinearOperator, float, np.ndarray]:
    """The factorized (C − σI)⁻¹ of the free vertices, C = M^-1/2 S M^-1/2, with σ and M^-1/2.

    The one sparse factorization every iteration of :func:`eigenpairs` reuses (its own step, so
    that a benchmark can time it apart from the iteration). Raises :class:`SolverFailure` for a
    vertex without area, a ``k`` the free vertices cannot hold, or a failed factorization.
    """
    stiffness, mass = operators
    diagonal = mass.diagonal()
    free = np.ones(len(diagonal), dtype=bool) if fixed is None else ~fixed
    diagonal = diagonal[free]
    if diagonal.min() <= 0:
        raise SolverFailure("a vertex has no area (zero lumped mass)")
    n = len(diagonal)
    if not 1 <= k < n:
        raise SolverFailure(f"k must lie in [1, {n - 1}] for {n} free vertices, got {k}")
    inverse_root = 1 / np.sqrt(diagonal)
    sigma = _shift(diagonal)
    try:
        factor = qdldl.Solver(_shifted_upper(stiffness.tocsr(), free, inverse_root, sigma), upper=True)
    except ValueError as exc:
        raise SolverFailure(f"the eigen-solver failed on this shape: {exc}") from exc
    return sla.LinearOperator((n, n), matvec=factor.solve, dtype=np.float64), sigma, inverse_root


def _require_a_spectrum(values: np.ndarray) -> None:
    """A Laplace–Beltrami spectrum is finite and non-negative: anything else is the discrete
    operator failing on this shape (a point cloud with one far outlier gave λ₁ = −0.021)."""
    if not np.isfinite(values).all():
        raise SolverFailure("the eigen-solver returned non-finite eigenvalues for this shape")
    if values[0] < -ORDER_TOLERANCE * max(float(np.abs(values).max()), 1.0):
        raise SolverFailure(
            f"this shape's Laplacian has a negative eigenvalue ({values[0]:.3g}), which no surface has: "
            "a point cloud with far outliers does this; remove them"
        )
    if values[-1] > MAX_EIGENVALUE:
        raise SolverFailure(f"eigenvalues above {MAX_EIGENVALUE:g} 1/m² are no scan's (λ_k = {values[-1]:.3g})")


def _shifted_upper(stiffness: sp.csr_matrix, free: np.ndarray, scale: np.ndarray, sigma: float) -> sp.csc_matrix:
    """Upper triangle of D S D − σ I on the ``free`` rows and columns, D = diag(``scale``), in CSC.

    What QDLDL factors, built in one pass over S's stored entries: the lower triangle of a
    symmetric CSR matrix, read as CSC, is its upper triangle. Taking the submatrix, scaling,
    shifting and triangle by sparse products and QDLDL's own conversion cost 5x more.
    """
    if not stiffness.has_canonical_format:  # sorted indices, at most one entry per position
        stiffness = stiffness.copy()
        stiffness.sum_duplicates()
    renumber = np.cumsum(free) - 1
    rows = np.repeat(np.arange(stiffness.shape[0]), np.diff(stiffness.indptr))
    columns = stiffness.indices
    keep = free[rows] & free[columns] & (columns <= rows)
    rows, columns = renumber[rows[keep]], renumber[columns[keep]]
    data = stiffness.data[keep] * scale[columns] * scale[rows]
    on_diagonal = rows == columns
    data[on_diagonal] -= sigma
    n = len(scale)
    pointers = np.r_[0, np.cumsum(np.bincount(rows, minlength=n))]
    upper = sp.csc_matrix((data, columns, pointers), shape=(n, n))
    unshifted = np.ones(n, dtype=bool)  # rows without a stored diagonal entry (isolated vertices)
    unshifted[rows[on_diagonal]] = False
    if unshifted.any():
        upper = (upper - sigma * sp.diags(unshifted.astype(np.float64))).tocsc()
    return upper
