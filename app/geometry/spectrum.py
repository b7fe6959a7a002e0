"""Truncated Laplace–Beltrami spectra: the first k eigenvalues of S x = λ M x.

A surface with boundary gets homogeneous Dirichlet conditions (boundary vertices removed from
the system); a closed one the plain spectrum, whose λ₁ = 0. Eigenvalues are in 1/m² when
the shape is in metres.

Speed: M is diagonal, so the pencil is turned into the standard symmetric problem
C = M^-1/2 S M^-1/2 and solved by ARPACK in shift-invert mode over one sparse LDLᵀ
factorization (:mod:`app.geometry.pencil`; SciPy's default path uses a general LU instead).
More than ``SLICED_ABOVE`` eigenvalues are solved in slices of the spectrum
(:mod:`app.geometry.slicing`), each over a factorization at its own shift, since ARPACK's own work grows
with the square of how many it is asked for.
"""

import numpy as np
import scipy.sparse as sp

from app.geometry.errors import SolverFailure
from app.geometry.laplacian import Operators
from app.geometry.pencil import NoConvergence, ShiftedPencil, lowest_shift
from app.geometry.slicing import SLICED_ABOVE, InconsistentSlices, sliced_eigenpairs

DEFAULT_K = 20
MAX_K = 200
# The largest eigenvalue a spectrum may hold, solved or sent: a shape 0.1 mm across (the
# smallest accepted) has λ_200 ≈ 1e12 1/m². The models run in float32 (max 3.4e38), and a
# value cast past that range came back as null from the union and the localizer.
MAX_EIGENVALUE = 1e15
# Solvers return λ₁ of a closed surface as ±1e-12·λ_k, and ties as tiny inversions.
ORDER_TOLERANCE = 1e-6
# ARPACK's implicit restarts for one solve: body parts, whole bodies and camera views (as cut and
# re-meshed) converge in a handful; a long thin strip's nearly degenerate spectrum took hundreds
# (a worker held for a minute) and is refused after these, a few seconds in, instead.
MAX_RESTARTS = 20


def shift_for(mass: sp.spmatrix) -> float:
    """The shift σ below every eigenvalue used for the shape with lumped mass ``mass`` (1/m²)."""
    return lowest_shift(mass.diagonal())


def eigenvalues(operators: Operators, k: int, fixed: np.ndarray | None = None) -> np.ndarray:
    """The ``k`` smallest eigenvalues of (S, M), ascending; see :func:`eigenpairs`."""
    return eigenpairs(operators, k, fixed, vectors=False)[0]


def eigenpairs(
    operators: Operators, k: int, fixed: np.ndarray | None = None, *, vectors: bool = True
) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``k`` smallest eigenvalues of (S, M), ascending, with x = 0 on ``fixed`` vertices.

    Beyond ``SLICED_ABOVE`` eigenpairs are solved in slices (if the slices cannot be joined with
    certainty, which they always could on the shapes measured, in one piece).

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
    pencil = _pencil(operators, k, fixed)
    if k > SLICED_ABOVE:
        try:
            values, functions = sliced_eigenpairs(pencil, k, vectors=vectors)
        except InconsistentSlices:
            return _solved(pencil, k, vectors=vectors)
        _require_a_spectrum(values)
        return values, functions
    return _solved(pencil, k, vectors=vectors)


def _solved(pencil: ShiftedPencil, k: int, *, vectors: bool) -> tuple[np.ndarray, np.ndarray | None]:
    """One ARPACK solve for the ``k`` lowest, at the shift below the spectrum, within MAX_RESTARTS."""
    factor = pencil.factor(pencil.lowest_shift)
    try:
        values, functions = pencil.nearest(factor, k, vectors=vectors, restarts=MAX_RESTARTS)
    except NoConvergence as exc:
        raise NoConvergence(
            f"{exc}; shapes converge within a few restarts, this one not within {MAX_RESTARTS}: its spectrum is "
            "nearly degenerate (a long thin strip?)"
        ) from exc
    _require_a_spectrum(values)
    return values, functions


def _pencil(operators: Operators, k: int, fixed: np.ndarray | None) -> ShiftedPencil:
    """The shape's pencil, refused when ``k`` is more than its free vertices can hold."""
    pencil = ShiftedPencil(operators, fixed)
    if not 1 <= k < pencil.size:
        raise SolverFailure(f"k must lie in [1, {pencil.size - 1}] for {pencil.size} free vertices, got {k}")
    return pencil


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
