"""The stored shapes' retrieval features in memory, kept in step with the database.

Reading every stored spectrum back at every query cost ~5 µs a row (SQLite: 0.5 s at 10⁵ shapes),
and PostgreSQL's 19-dimensional GiST index pruned poorly at 10⁶ (p99 52 ms). Both stores now rank
from this copy with :func:`app.retrieval.distance.top_matches`, and read from the database only
what changed since their last query.
"""

import threading
from collections.abc import Hashable
from typing import Protocol

import numpy as np

from app.retrieval.distance import Ranked, features, top_matches


class RowSource(Protocol):
    """One store's rows as one transaction sees them (one snapshot for every call).

    The contract the copy relies on: while ``version`` is unchanged, rows are only ever added,
    each with a key above every key visible before it (the store guarantees it: SQLite's rowid
    under its single writer, PostgreSQL's ``seq`` taken under one lock by every insert)."""

    def version(self) -> Hashable:
        """Changes whenever a row may have gone: a deletion, another file or table."""
        ...

    def last(self) -> int:
        """The greatest key visible (0: no rows)."""
        ...

    def spectra_after(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """(keys (n,), spectra (n, k)) of the rows past ``key``, keys ascending."""
        ...


class FeatureCopy:
    """Keys, features (m, k - 1) and their squared norms of every stored shape, in key order.

    Each query reads just the rows past the last key the copy has; one whose snapshot is older
    than the copy (another thread read first) sees a prefix of it; a changed version reads
    everything again. Ranking is then what reading every row gave: the same features, in the
    same order. Thread-safe: the service's k-NN requests share one store.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._version: Hashable | None = None
        self._keys = np.zeros(0, dtype=np.int64)
        self._features = np.zeros((0, 0))
        self._squared = np.zeros(0)

    def synced(self, source: RowSource) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(keys (m,), features (m, k - 1), squared norms (m,)) as ``source``'s snapshot sees them."""
        version, last = source.version(), source.last()
        with self._lock:
            known = int(self._keys[-1]) if len(self._keys) else 0
            if version != self._version:
                self._version = version
                self._keys, self._features = _features_after(source, 0)
                self._squared = (self._features**2).sum(axis=1)
            elif last > known:
                keys, added = _features_after(source, known)
                self._keys = np.concatenate([self._keys, keys])
                self._features = np.concatenate([self._features.reshape(-1, added.shape[1]), added])
                self._squared = np.concatenate([self._squared, (added**2).sum(axis=1)])
            end = int(np.searchsorted(self._keys, last, side="right"))
            return self._keys[:end], self._features[:end], self._squared[:end]

    def nearest(self, source: RowSource, spectra: np.ndarray, top: int) -> Ranked:
        """The ``top`` stored shapes nearest any of ``spectra`` as ``source``'s snapshot sees them
        (:func:`top_matches`), each row given by its key in the database."""
        keys, stored, squared = self.synced(source)
        if len(keys) == 0:
            return Ranked(keys, np.zeros(0), np.zeros(0, dtype=np.int64))
        ranked = top_matches(np.asarray(spectra, dtype=np.float64), stored, squared, top)
        return ranked._replace(rows=keys[ranked.rows])


def _features_after(source: RowSource, key: int) -> tuple[np.ndarray, np.ndarray]:
    keys, spectra = source.spectra_after(key)
    if len(keys) == 0:
        return np.zeros(0, dtype=np.int64), np.zeros((0, 0))
    return keys, features(spectra)
