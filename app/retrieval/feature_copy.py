"""The stored shapes' retrieval features in memory, kept in step with the database.

Reading every stored spectrum back at every query cost ~5 µs a row (SQLite: 0.5 s at 10⁵ shapes),
and PostgreSQL's 19-dimensional GiST index pruned poorly at 10⁶ (p99 52 ms). Both stores now rank
from this copy (:class:`app.retrieval.axis_index.AxisIndex` and
:func:`app.retrieval.distance.top_matches`), and read from the database only what changed since
their last query.
"""

import threading
from collections.abc import Hashable
from typing import NamedTuple, Protocol

import numpy as np

from app.retrieval.axis_index import AxisIndex, merged
from app.retrieval.distance import Ranked, features, top_matches

# Rows added since the index was built are scanned whole by every query until there are more
# than this many, or this share of the index; the index is then built again (a sort of every
# row: ~0.2 s at 10⁶, once per 6·10⁴ rows added there).
TAIL_ROWS = 1 << 14
TAIL_SHARE = 1 / 16


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


class Snapshot(NamedTuple):
    """The rows one query sees: the sorted index (its rows past ``last`` hidden) and the rows added
    since it was built (keys, features, squared norms, in key order, up to ``last``)."""

    index: AxisIndex
    keys: np.ndarray
    features: np.ndarray
    squared: np.ndarray
    last: int


class FeatureCopy:
    """Keys, features (k - 1 each) and their squared norms of every stored shape: most in an
    :class:`AxisIndex`, the rows added since it was built in key order beside it.

    Each query reads just the rows past the last key the copy has; one whose snapshot is older
    than the copy (another thread read first) sees a prefix of it; a changed version reads
    everything again. Ranking is then what reading every row gave: the same features, the same
    order. Thread-safe: the service's k-NN requests share one store; arrays are replaced, never
    changed, so a query ranks outside the lock.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._version: Hashable | None = None
        self._known = 0
        self._index = AxisIndex(*_empty())
        self._keys, self._features, self._squared = _empty()

    def synced(self, source: RowSource) -> Snapshot:
        """The stored rows as ``source``'s snapshot sees them."""
        version, last = source.version(), source.last()
        with self._lock:
            if version != self._version:
                self._version = version
                self._index = AxisIndex(*_features_after(source, 0))
                self._keys, self._features, self._squared = _empty()
                self._known = int(self._index.keys.max()) if len(self._index) else 0
            elif last > self._known:
                keys, added, squared = _features_after(source, self._known)
                self._keys = np.concatenate([self._keys, keys])
                self._features = np.concatenate([self._features.reshape(-1, added.shape[1]), added])
                self._squared = np.concatenate([self._squared, squared])
                self._known = int(keys[-1])
                if len(self._keys) > max(TAIL_ROWS, TAIL_SHARE * len(self._index)):
                    self._reindex()
            end = int(np.searchsorted(self._keys, last, side="right"))
            return Snapshot(self._index, self._keys[:end], self._features[:end], self._squared[:end], last)

    def nearest(self, source: RowSource, spectra: np.ndarray, top: int) -> Ranked:
        """The ``top`` stored shapes nearest any of ``spectra`` as ``source``'s snapshot sees them
        (ranked as :func:`top_matches` ranks every row), each row given by its key in the database."""
        seen = self.synced(source)
        spectra = np.asarray(spectra, dtype=np.float64)
        found = [seen.index.nearest(spectra, top, seen.last)]
        if len(seen.keys):
            ranked = top_matches(spectra, seen.features, seen.squared, top)
            found.append(ranked._replace(rows=seen.keys[ranked.rows]))
        return merged(found, top)

    def _reindex(self) -> None:
        """One index of every row: the rows added since the last are no longer scanned whole."""
        index = self._index
        self._index = AxisIndex(
            np.concatenate([index.keys, self._keys]),
            np.concatenate([index.features.reshape(-1, self._features.shape[1]), self._features]),
            np.concatenate([index.squared, self._squared]),
        )
        self._keys, self._features, self._squared = _empty()


def _empty() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.zeros(0, dtype=np.int64), np.zeros((0, 0)), np.zeros(0)


def _features_after(source: RowSource, key: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(keys, features, squared norms) of the rows past ``key``."""
    keys, spectra = source.spectra_after(key)
    if len(keys) == 0:
        return _empty()
    stored = features(spectra)
    return keys, stored, (stored**2).sum(axis=1)
