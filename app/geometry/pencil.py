"""The pencil (S, M) as the standard symmetric problem C = M^-1/2 S M^-1/2, factorized at any shift.

M is diagonal, so C has the pencil's eigenvalues and is as sparse as S. Each shift gets one
sparse LDLᵀ factorization of C − σI (QDLDL, AMD ordering), which serves twice: as the
shift-invert operator every ARPACK step applies, and, by Sylvester's law of inertia (the
negative pivots of D count the eigenvalues below σ), as an exact count that lets a spectrum be
solved in slices (:mod:`app.geometry.slicing`).
"""

from functools import cached_property

import numpy as np
import qdldl
import scipy.sparse as sp
import scipy.sparse.linalg as sla

from app.geometry.errors import SolverFailure, library_reason
from app.geometry.laplacian import Operators

# The lowest shift sits below λ₁ = 0 of a closed surface by this fraction of 1/area, i.e. well
# under any eigenvalue of the shape but on its own scale, so the method is scale-equivariant.
RELATIVE_SHIFT = 1e-2
# ARPACK's relative tolerance on the shift-inverted Ritz values; 0 means machine precision. A
# looser 1e-10 saved some solves but took a member of the next cluster for the sphere's λ₂₀.
ARPACK_TOL = 0.0


class NoConvergence(SolverFailure):
    """ARPACK did not converge within the restarts it was allowed."""


class Factor:
    """(C − σI)⁻¹ as a linear operator and, read from its pivots when asked (a copy of the factor:
    a few ms on a body-sized mesh), how many eigenvalues of C lie below σ.

    Moved to another shift (:meth:`move`), the factor keeps its ordering and symbolic analysis and
    only refactors numerically, a fraction of a new factorization's cost (decision 024).
    """

    def __init__(self, upper: sp.csc_matrix, shift: float):
        try:
            self._solver = qdldl.Solver(upper, upper=True)
        except ValueError as exc:
            raise SolverFailure(f"the eigen-solver failed on this shape: {library_reason(exc)}") from exc
        self.shift = shift
        self._pattern = (upper.indptr, upper.indices)
        n = upper.shape[0]
        self.operator = sla.LinearOperator((n, n), matvec=self._solver.solve, dtype=np.float64)

    def move(self, upper: sp.csc_matrix, shift: float) -> bool:
        """Refactor in place for ``upper`` at ``shift``; False (nothing changed) when its sparsity
        differs from the factor's, which then needs a new analysis."""
        if not all(np.array_equal(a, b) for a, b in zip(self._pattern, (upper.indptr, upper.indices), strict=True)):
            return False
        try:
            self._solver.update(upper, upper=True)
        except ValueError as exc:
            raise SolverFailure(f"the eigen-solver failed on this shape: {library_reason(exc)}") from exc
        self.shift = shift
        self.__dict__.pop("_pivots", None)
        return True

    @cached_property
    def _pivots(self) -> np.ndarray:
        pivots = self._solver.factors()[1]
        if not np.isfinite(pivots).all() or (pivots == 0).any():
            raise SolverFailure("the eigen-solver failed on this shape: a singular shifted system")
        return pivots

    @property
    def below(self) -> int:
        """The number of eigenvalues of C below the shift (Sylvester: the negative pivots)."""
        return int(np.count_nonzero(self._pivots < 0))


class ShiftedPencil:
    """The free vertices' C, ready to be factorized at any shift and solved near it.

    Parameters
    ----------
    operators : Operators
        Stiffness S and diagonal lumped mass M of the whole shape.
    fixed : (n,) bool array or None
        Dirichlet vertices, removed from the system; None for a closed shape.

    Raises
    ------
    SolverFailure
        For a free vertex without area.
    """

    def __init__(self, operators: Operators, fixed: np.ndarray | None = None):
        stiffness, mass = operators
        diagonal = mass.diagonal()
        self.free = np.ones(len(diagonal), dtype=bool) if fixed is None else ~fixed
        diagonal = diagonal[self.free]
        if diagonal.size == 0 or diagonal.min() <= 0:
            raise SolverFailure("a vertex has no area (zero lumped mass)")
        self.stiffness = stiffness.tocsr()
        self.inverse_root = 1 / np.sqrt(diagonal)
        self.size = len(diagonal)
        self.lowest_shift = lowest_shift(diagonal)

    def factor(self, shift: float, reuse: Factor | None = None) -> Factor:
        """The LDLᵀ of C − ``shift``·I (raises :class:`SolverFailure` when it breaks down); with
        ``reuse``, that factor moved to ``shift`` (its old shift is gone) where its sparsity allows."""
        upper = _shifted_upper(self.stiffness, self.free, self.inverse_root, shift)
        if reuse is not None and reuse.move(upper, shift):
            return reuse
        return Factor(upper, shift)

    def nearest(
        self, factor: Factor, count: int, *, vectors: bool = False, restarts: int | None = None
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """The ``count`` eigenvalues of C nearest ``factor.shift``, ascending, by ARPACK in
        shift-invert mode, with the M-orthonormal eigenfunctions of (S, M) when ``vectors``.

        ``restarts`` bounds ARPACK's implicit restarts (None: SciPy's 10 n); past it,
        :class:`NoConvergence`.
        """
        start = np.random.default_rng(0).standard_normal(self.size)
        try:
            # In shift-invert mode with OPinv given, eigsh reads only the shape and dtype of its
            # first argument: C itself is never multiplied, so it is never assembled.
            result = sla.eigsh(
                factor.operator,
                k=count,
                sigma=factor.shift,
                OPinv=factor.operator,
                which="LM",
                v0=start,
                tol=ARPACK_TOL,
                return_eigenvectors=vectors,
                maxiter=restarts,
            )
        except sla.ArpackNoConvergence as exc:
            raise NoConvergence(f"the eigen-solver did not converge on this shape: {library_reason(exc)}") from exc
        except (ValueError, sla.ArpackError) as exc:
            raise SolverFailure(f"the eigen-solver failed on this shape: {library_reason(exc)}") from exc
        values, standard_vectors = (result, None) if not vectors else result
        order = np.argsort(values)
        if standard_vectors is None:
            return values[order], None
        # x = M^-1/2 y turns orthonormal eigenvectors of C into M-orthonormal ones of (S, M).
        return values[order], self.inverse_root[:, None] * standard_vectors[:, order]


def lowest_shift(lumped_mass: np.ndarray) -> float:
    """The shift below every eigenvalue for a shape of lumped mass ``lumped_mass`` (1/m²)."""
    return -RELATIVE_SHIFT / float(lumped_mass.sum())


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
