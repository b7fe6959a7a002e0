"""The ShapeDNA distance used for retrieval.

Euclidean distance between log-eigenvalues λ₂…λ_k: the log makes a 5 % change weigh the same
for a low and a high eigenvalue (raw differences would be ruled by the top of the spectrum),
and λ₁ is left out because it is 0 for every closed surface. No area normalisation: body size
is part of what identifies a person.
"""

from typing import NamedTuple

import numpy as np
from threadpoolctl import ThreadpoolController

FLOOR = 1e-9
# Stored rows ranked per matrix product in top_matches: blocks that stay in cache (11 profile
# queries × 2¹² rows, 0.4 MB), where all of 10⁶ rows at once were ~90 MB of temporaries, twice.
# 2¹² to 2¹⁶ rows measured alike for one query; 2¹² best for a profile's 11 (one BLAS thread).
BLOCK_ROWS = 1 << 12
SINGLE_BLOCK_ROWS = 1 << 16  # one query: a matrix-vector product per block
# Rows sampled for top_matches' bound: ~top / SAMPLE_ROWS of all rows are then measured exactly.
SAMPLE_ROWS = 4096
BLAS = ThreadpoolController()  # products on one BLAS thread (top_matches says why)


def features(spectra: np.ndarray) -> np.ndarray:
    """(m, k) spectra → (m, k - 1) retrieval features."""
    return np.log(np.clip(np.atleast_2d(spectra)[:, 1:], FLOOR, None))


def distances(query: np.ndarray, spectra: np.ndarray) -> np.ndarray:
    """(m,) distances from one (k,) spectrum to each of (m, k) stored spectra."""
    if len(spectra) == 0:
        return np.zeros(0)
    return np.linalg.norm(features(spectra) - features(query), axis=1)


def nearest_of(queries: np.ndarray, spectra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(m,) each of (m, k) stored spectra at its distance to the nearest of one (k,) or several
    (n, k) query spectra, and (m,) which query that is: how a share profile ranks (``/v1/retrieve``
    with two operands whose overlap is not told)."""
    each = np.stack([distances(query, spectra) for query in np.atleast_2d(np.asarray(queries, dtype=np.float64))])
    return each.min(axis=0), each.argmin(axis=0)


class Ranked(NamedTuple):
    """Stored rows in ranking order, their distances, and which query each is nearest to."""

    rows: np.ndarray
    distances: np.ndarray
    queries: np.ndarray


def top_matches(
    queries: np.ndarray, stored: np.ndarray, squared: np.ndarray, top: int, ties: np.ndarray | None = None
) -> Ranked:
    """The ``top`` rows of (m, k - 1) stored :func:`features` nearest to one (k,) or any of (n, k)
    query spectra, exactly as ``np.argsort(nearest_of(queries, spectra)[0], kind="stable")[:top]``
    orders them, with their distances and the query each is nearest to; ``squared``: each stored
    row's squared norm; ``ties``: (m,) distinct numbers that order rows at equal distances (default:
    their index, the stable order; rows kept in another order pass their keys).

    Why not :func:`nearest_of` and a sort: its differences take a pass over every stored row per
    query, and a stable sort of every distance is slow at 10⁶ rows. Here one matrix product
    ranks every row by |f|² − 2 f·q + |q|², which float64 rounding moves by less than ``slack``
    from the true squared distance; only rows that rounding could have kept out of the top are
    then measured by differences and sorted (distance, then row: the stable order). The products
    run on one BLAS thread: a block's is too small to share, and with both cores busy (the solver
    workers' work) OpenBLAS's two threads made a query over 10⁶ rows several times slower.
    """
    asked = features(queries)
    asked_squared = (asked**2).sum(axis=1)[:, None]
    approximate = np.empty(len(stored))
    with BLAS.limit(limits=1, user_api="blas"):
        if len(asked) == 1:  # one matrix-vector product per block, no minimum to take
            for start in range(0, len(stored), SINGLE_BLOCK_ROWS):
                block = slice(start, start + SINGLE_BLOCK_ROWS)
                approximate[block] = stored[block] @ (-2 * asked[0])
            approximate += asked_squared[0, 0]
        else:
            for start in range(0, len(stored), BLOCK_ROWS):  # (queries, block) temporaries, not (queries, rows)
                block = slice(start, start + BLOCK_ROWS)
                approximate[block] = (asked_squared - 2 * (asked @ stored[block].T)).min(axis=0)
    approximate += squared
    if not 0 < top < len(stored):
        candidates = np.arange(len(stored))
    else:
        slack = rounding_slack(squared.max(), asked_squared.max())
        # The top-th smallest of a sample of the rows is at least the top-th of all: a bound as
        # good for choosing candidates, at a fraction of a partition of every row.
        sample = approximate[:: max(1, len(stored) // max(SAMPLE_ROWS, top))]
        bound = np.partition(sample, top - 1)[top - 1] if len(sample) >= top else approximate.max()
        candidates = np.flatnonzero(approximate <= bound + slack)
    return ranked_exactly(asked, stored, candidates, candidates if ties is None else ties[candidates], top)


def rounding_slack(stored_squared: float, asked_squared: float) -> float:
    """How far float64 rounding can move |f|² − 2 f·q + |q|² from the true squared distance, for
    rows of squared norm ≤ ``stored_squared`` and a query of ``asked_squared``: (|f| + |q|)² ≤
    2 (|f|² + |q|²) bounds every term of the product; 64 ulps of that, twice."""
    return 2 * 64 * np.finfo(np.float64).eps * 2 * (stored_squared + asked_squared)


def ranked_exactly(asked: np.ndarray, stored: np.ndarray, rows: np.ndarray, ties: np.ndarray, top: int) -> Ranked:
    """The ``top`` of ``rows`` of (m, k - 1) stored features by their distance to the nearest of the
    (n, k - 1) ``asked`` features, measured by differences as :func:`nearest_of` measures every
    row, ties ordered by ``ties`` (one per row of ``rows``)."""
    each = np.stack([np.linalg.norm(stored[rows] - query, axis=1) for query in asked])
    distance, query = each.min(axis=0), each.argmin(axis=0)
    order = np.lexsort((ties, distance))[:top]
    return Ranked(rows[order], distance[order], query[order])
