"""The k smallest eigenpairs of a pencil, solved in slices of the spectrum.

Why: ARPACK's work beyond the triangular solves grows with the square of how many eigenvalues
it is asked for (its Lanczos basis of 2k + 1 vectors is re-orthogonalized at every step), so at
k = 100 on a 13 k-vertex body that overhead, not the factorization, was two thirds of the time.
Here ARPACK is asked for at most ``SLICE_SIZE`` (+ a margin) eigenvalues at a time: the lowest
slice at the usual shift below the spectrum, each next one around a shift placed past the last
known eigenvalue, over the previous slice's factorization moved there (refactored numerically,
its ordering and analysis kept: a third of a new one's cost).

Why it is exact: the factorization at a shift σ also counts the eigenvalues below σ (Sylvester's
inertia), so the eigenvalues ARPACK finds around σ get their indices in the spectrum, not a
guess. Each slice must reach down into the previous one; where the two overlap, both solves must
agree (to ``OVERLAP_TOLERANCE``), so a slice that missed an eigenvalue or took one from the next
cluster shows as a disagreement, and the caller falls back to one plain solve.

Eigenfunctions come from each slice's own solve. Those of distinct eigenvalues are orthogonal
whichever solve found them; a cluster cut by a slice's edge is the exception (two solves may
each return a direction of the same eigenspace). So two slices' eigenfunctions are joined at
the widest gap of their overlap, and the joined basis must be M-orthonormal, or the caller
solves in one piece.
"""

import math

import numpy as np

from app.geometry.errors import SolverFailure
from app.geometry.pencil import Factor, NoConvergence, ShiftedPencil

# Eigenvalues ARPACK is asked for per slice, and the k from which slicing pays: one solve and
# slices of 16 to 50 measured side by side on the 13 k body, as the solver workers run
# (``docs/decisions/047-eigenpairs-beyond-48-are-solved-in-slices-of-32.md``).
SLICE_SIZE = 32
SLICED_ABOVE = 48
# Extra eigenvalues asked for around each interior shift, so that consecutive slices overlap.
MARGIN = 4
# Two slices' values of one eigenvalue, relative to the spectrum's mean spacing at that point:
# both are solved to machine precision, so anything beyond rounding is a mislabelled eigenvalue.
OVERLAP_TOLERANCE = 1e-6
# ARPACK's implicit restarts allowed per slice. A slice converges in 1–3; one whose edge cuts an
# exactly degenerate cluster (a symmetric mesh's) may never converge, and is asked again for more.
SLICE_RESTARTS = 10
# An eigenvalue closer to an interior shift than this, relative to the spectrum's mean spacing,
# makes that shift's count of the eigenvalues below it ambiguous (the sign of a pivot ~0).
SINGULAR_DISTANCE = 1e-9
# The joined eigenfunctions' largest departure from M-orthonormality accepted.
ORTHONORMAL_TOLERANCE = 1e-10


class InconsistentSlices(Exception):
    """Two slices disagree, or a slice cannot be tied to the known ones: solve in one piece."""


def sliced_eigenpairs(
    pencil: ShiftedPencil, k: int, size: int = SLICE_SIZE, *, vectors: bool = False
) -> tuple[np.ndarray, np.ndarray | None]:
    """The ``k`` smallest eigenvalues of ``pencil``, ascending, in slices of about ``size``, with
    their M-orthonormal eigenfunctions on the free vertices when ``vectors``.

    Raises
    ------
    InconsistentSlices
        When the slices cannot be joined with certainty (the caller solves in one piece).
    SolverFailure
        When a factorization or ARPACK breaks down.
    """
    assert size >= 2, "a slice's spacing is measured between at least two eigenvalues"
    slices = math.ceil(k / size)
    size = math.ceil(k / slices)
    factor = pencil.factor(pencil.lowest_shift)
    if factor.below:  # a negative eigenvalue: the plain solve reports it as such
        raise InconsistentSlices("an eigenvalue lies below the lowest shift")
    values = np.full(k, np.nan)
    values[:size], functions = pencil.nearest(factor, size, vectors=vectors)
    top = size - 1  # values[: top + 1] are known
    while top < k - 1:
        wanted = min(size, k - 1 - top)
        spacing = (values[top] - values[0]) / top
        shift = values[top] + spacing * (wanted + 1) / 2
        try:
            factor = pencil.factor(shift, reuse=factor)  # the last slice's, refactored
            first, block, block_functions = _block_reaching(pencil, factor, top, size, vectors)
        except SolverFailure as exc:  # LDLᵀ without pivoting, or ARPACK, broke down at this shift
            raise InconsistentSlices(f"the slice at {shift:g} broke down: {exc}") from exc
        if np.abs(block - factor.shift).min() < SINGULAR_DISTANCE * spacing:
            raise InconsistentSlices(f"the shift {factor.shift:g} lies on an eigenvalue")
        overlap = values[first : top + 1]
        if np.abs(block[: len(overlap)] - overlap).max() > OVERLAP_TOLERANCE * spacing:
            raise InconsistentSlices("two slices disagree where they overlap")
        new = block[len(overlap) :][: k - 1 - top]
        if vectors:
            cut = _widest_gap(values, first, top, new[0])
            functions = np.hstack([functions[:, :cut], block_functions[:, cut - first : len(overlap) + len(new)]])
        values[top + 1 : top + 1 + len(new)] = new
        top += len(new)
    if not vectors:
        return values, None
    return values, _orthonormal(pencil, functions)


def _widest_gap(values: np.ndarray, first: int, top: int, next_value: float) -> int:
    """Where a new slice's eigenfunctions take over from the known ones: the index in the overlap
    ``first`` … ``top`` (or just past it) after the widest gap, so that a cluster is cut, if at
    all, where its members lie farthest apart (the whole overlap from the new slice when it
    reaches the lowest eigenvalue)."""
    if first == 0:
        return 0
    gaps = np.diff(np.r_[values[first - 1 : top + 1], next_value])
    return first + int(np.argmax(gaps))


def _orthonormal(pencil: ShiftedPencil, functions: np.ndarray) -> np.ndarray:
    """``functions``, refused unless M-orthonormal (two solves that each returned a direction of
    one eigenspace cut by a slice's edge leave two nearly parallel columns)."""
    standard = functions / pencil.inverse_root[:, None]  # M^1/2 x: M-inner products become dot products
    if np.abs(standard.T @ standard - np.eye(functions.shape[1])).max() > ORTHONORMAL_TOLERANCE:
        raise InconsistentSlices("the slices' eigenfunctions are not M-orthonormal where they join")
    return functions


def _block_reaching(
    pencil: ShiftedPencil, factor: Factor, top: int, size: int, vectors: bool
) -> tuple[int, np.ndarray, np.ndarray | None]:
    """The index of the lowest of the eigenvalues nearest ``factor.shift``, those eigenvalues and
    (with ``vectors``) their eigenfunctions, asking ARPACK for more until they reach down to index
    ``top`` and beyond it (or until ARPACK converges).

    As many are asked for as lie between the known ones and the shift, twice (the shift is meant
    to sit in the middle of the slice), and at least a slice's ``size``, plus ``MARGIN``: a
    clustered spectrum (a symmetric mesh's) can leave the shift in a gap with none below it, and
    fewer cost ARPACK about as much (so the last slice, however few it still needs, asks as many).
    """
    unknown_below = factor.below - 1 - top
    if unknown_below < 0:
        raise InconsistentSlices("the shift lies below an eigenvalue already known")
    count = max(2 * unknown_below, size) + MARGIN
    while True:
        count = min(count, pencil.size - 1)
        try:
            found, functions = pencil.nearest(factor, count, vectors=vectors, restarts=SLICE_RESTARTS)
        except NoConvergence:
            found = functions = None
        if found is not None:
            first = factor.below - int(np.count_nonzero(found < factor.shift))
            if first < 0:
                raise InconsistentSlices("more eigenvalues found below the shift than lie there")
            if first <= top < first + count - 1:
                return first, found, functions
        if count == pencil.size - 1:
            raise InconsistentSlices("a slice cannot reach the known eigenvalues")
        count += count // 2 + 1
