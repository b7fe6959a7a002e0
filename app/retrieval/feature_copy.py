"""The stored shapes' retrieval features in memory, kept in step with the database.

Reading every stored spectrum back at every query costs a pass over the database, and
PostgreSQL's 19-dimensional GiST index pruned poorly at 10⁶ shapes. Both stores now rank
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

# Rows added since the index was built are scanned whole by every query, and rows deleted since
# are carried unanswered, until together they are more than this many, or this share of the
# index; the index is then built again (a sort of every row, once per 6·10⁴ rows added or
# deleted at 10⁶).
TAIL_ROWS = 1 << 14
TAIL_SHARE = 1 / 16
# The deletions the database's log keeps (a few MB), and so each copy's: a copy that last read
# the log before the oldest of them reads every row again (as an open does) instead of
# the deletions since; a query whose snapshot is older reads its snapshot whole.
DELETIONS_KEPT = 100_000


class RowSource(Protocol):
    """One store's rows as one transaction sees them (one snapshot for every call).

    The contract the copy relies on: while ``version`` is unchanged, a row is added with a key
    above every key visible before it (SQLite's rowid under its single writer, PostgreSQL's
    ``seq`` taken under one lock by every insert), and every deletion is logged in the order
    deletions become visible. SQLite may give the newest row's key again once that row is
    deleted: the copy then reads everything again."""

    def version(self) -> Hashable:
        """Changes whenever the rows may be others altogether: another file or table."""
        ...

    def deletions(self) -> int:
        """The log's last position (0: no deletion ever); positions grow, with gaps at times."""
        ...

    def deleted_after(self, position: int) -> tuple[np.ndarray, np.ndarray]:
        """(positions, keys) of the deletions logged past ``position``."""
        ...

    def forgotten(self) -> int:
        """The position through which the log may have been pruned: a copy that last read it
        before that cannot tell what was deleted since, and reads every row again."""
        ...

    def last(self) -> int:
        """The greatest key visible (0: no rows)."""
        ...

    def spectra_after(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """(keys (n,), spectra (n, k)) of the rows past ``key``, keys ascending."""
        ...


class Snapshot(NamedTuple):
    """The rows one query sees: the sorted index and the rows added since it was built (keys,
    features, squared norms, in key order), up to key ``last``, less the rows of ``stale`` keys
    (deleted after the query's snapshot: SQLite may have given their keys to other rows)."""

    index: AxisIndex
    keys: np.ndarray
    features: np.ndarray
    squared: np.ndarray
    last: int
    stale: np.ndarray


class FeatureCopy:
    """Keys, features (k - 1 each) and their squared norms of every stored shape: most in an
    :class:`AxisIndex`, the rows added since it was built in key order beside it.

    Each query reads just the rows past the last key the copy has and the deletions logged since
    its last read (a deleted row stops being answered; the index drops them when it is built
    again). A changed version, the deletion of the newest row (SQLite may give its key to the
    next row), or a log pruned past the copy's last read, reads everything again. A query whose
    snapshot is older than the copy (another thread read first) sees the copy's rows up to its
    last key, less those deleted since its snapshot: rows it would still see are not answered
    once another query saw them deleted; older than every deletion the copy remembers (at most
    :data:`DELETIONS_KEPT`), it reads its snapshot whole. Ranking is then what reading every row
    gave: the same features, the same order. Thread-safe: the service's k-NN requests share one
    store; arrays are replaced, never changed, so a query ranks outside the lock.
    """

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._version: Hashable | None = None
        self._known = 0  # the greatest key read, a row still stored
        self._deletions = 0  # the log's last position applied
        # The log's deletions applied since the last full read (which had read the log up to
        # _log_start; or since the last of them forgotten, past DELETIONS_KEPT): positions and keys.
        self._log_start = 0
        self._log_positions = self._log_keys = np.zeros(0, dtype=np.int64)
        self._index = AxisIndex(*_empty())
        self._keys, self._features, self._squared = _empty()

    def synced(self, source: RowSource) -> Snapshot:
        """The stored rows as ``source``'s snapshot sees them (less rows deleted since, see above)."""
        version, last, deletions = source.version(), source.last(), source.deletions()
        with self._lock:
            if version == self._version and deletions > self._deletions:
                if not self._applied_deletions(source):
                    self._version = None
                self._deletions = deletions
            if version != self._version:
                self._version = version
                self._index = AxisIndex(*_features_after(source, 0))
                self._keys, self._features, self._squared = _empty()
                self._known = int(self._index.keys.max()) if len(self._index) else 0
                self._deletions = self._log_start = deletions
                self._log_positions = self._log_keys = np.zeros(0, dtype=np.int64)
            elif deletions == self._deletions and last > self._known:  # an older snapshot adds nothing
                keys, added, squared = _features_after(source, self._known)
                self._keys = np.concatenate([self._keys, keys])
                self._features = _rows(self._features, added)
                self._squared = np.concatenate([self._squared, squared])
                self._known = int(keys[-1])
            if len(self._keys) + self._index.dead > max(TAIL_ROWS, TAIL_SHARE * len(self._index)):
                self._reindex()
            if deletions >= self._log_start:
                stale = self._log_keys[self._log_positions > deletions]
                kept = (self._keys <= last) & ~np.isin(self._keys, stale)
                return Snapshot(self._index, self._keys[kept], self._features[kept], self._squared[kept], last, stale)
        return Snapshot(AxisIndex(*_features_after(source, 0)), *_empty(), last, np.zeros(0, dtype=np.int64))

    def nearest(self, source: RowSource, spectra: np.ndarray, top: int) -> Ranked:
        """The ``top`` stored shapes nearest any of ``spectra`` as ``source``'s snapshot sees them
        (ranked as :func:`top_matches` ranks every row), each row given by its key in the database."""
        seen = self.synced(source)
        spectra = np.asarray(spectra, dtype=np.float64)
        found = [seen.index.nearest(spectra, top, seen.last, seen.stale)]
        if len(seen.keys):
            ranked = top_matches(spectra, seen.features, seen.squared, top)
            found.append(ranked._replace(rows=seen.keys[ranked.rows]))
        return merged(found, top)

    def _applied_deletions(self, source: RowSource) -> bool:
        """Stop answering the rows deleted since the copy last read the log; False, with nothing
        applied, where the log cannot say which (pruned past that read, before reading it) or
        the newest row went (SQLite may give its key to the next row): everything is read again."""
        if self._deletions < source.forgotten():
            return False
        positions, deleted = source.deleted_after(self._deletions)
        if self._known in deleted:
            return False
        self._forget(positions, deleted)
        return True

    def _forget(self, positions: np.ndarray, deleted: np.ndarray) -> None:
        """Rows of ``deleted`` keys (logged at ``positions``) no longer answered; keys the copy
        never read are ignored."""
        positions = np.concatenate([self._log_positions, positions])
        keys = np.concatenate([self._log_keys, deleted])
        if len(positions) > DELETIONS_KEPT:  # forgotten as the database forgets them
            self._log_start = int(positions[-DELETIONS_KEPT - 1])
            positions, keys = positions[-DELETIONS_KEPT:], keys[-DELETIONS_KEPT:]
        self._log_positions, self._log_keys = positions, keys
        self._index = self._index.without(deleted)
        kept = ~np.isin(self._keys, deleted)
        self._keys, self._features, self._squared = self._keys[kept], self._features[kept], self._squared[kept]

    def _reindex(self) -> None:
        """One index of every stored row: the rows added since the last are no longer scanned
        whole, the deleted ones no longer carried."""
        keys, stored, squared = self._index.live()
        self._index = AxisIndex(
            np.concatenate([keys, self._keys]), _rows(stored, self._features), np.concatenate([squared, self._squared])
        )
        self._keys, self._features, self._squared = _empty()


def _empty() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    return np.zeros(0, dtype=np.int64), np.zeros((0, 0)), np.zeros(0)


def _rows(*parts: np.ndarray) -> np.ndarray:
    """Feature rows one after the other; an empty part may be (0, 0)."""
    filled = [part for part in parts if len(part)]
    return np.concatenate(filled) if filled else np.zeros((0, 0))


def _features_after(source: RowSource, key: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(keys, features, squared norms) of the rows past ``key``."""
    keys, spectra = source.spectra_after(key)
    if len(keys) == 0:
        return _empty()
    stored = features(spectra)
    return keys, stored, (stored**2).sum(axis=1)
