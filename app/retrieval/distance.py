"""The ShapeDNA distance used for retrieval.

Euclidean distance between log-eigenvalues λ₂…λ_k: the log makes a 5 % change weigh the same
for a low and a high eigenvalue (raw differences would be ruled by the top of the spectrum),
and λ₁ is left out because it is 0 for every closed surface. No area normalisation: body size
is part of what identifies a person.
"""

import numpy as np

FLOOR = 1e-9


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
    return nearest_in_features(np.atleast_2d(np.asarray(queries, dtype=np.float64)), features(spectra))


def nearest_in_features(queries: np.ndarray, stored: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`nearest_of` for (m, k - 1) stored :func:`features` computed once (a store's
    in-memory copy) and (n, k) query spectra."""
    each = np.stack([np.linalg.norm(stored - query, axis=1) for query in features(queries)])
    return each.min(axis=0), each.argmin(axis=0)
