"""Stored features sorted along their principal axis, so that a k-NN query measures only the rows
whose position on that axis lies within reach of the query's.

Why: a position on a unit axis u never moves more than the distance does, |u·f − u·q| ≤ |f − q|,
so once some ``top`` rows are known within a distance ``bound`` of the query, a row further than
``bound`` along the axis cannot rank among the top. People spread most along one direction of
the log-spectrum (size: every log-eigenvalue moves together), so the rows within reach of one
query are a small slice of the sorted rows: at 10⁶ stored bodies a query measures ~1/10 of them.
The answer is the exact ranking :func:`top_matches` gives over every row (its stable order, bit
for bit): the rows kept are measured by differences, and the reach is widened by more than
float64 rounding could move a position, a distance or a product.
"""

import copy

import numpy as np

from app.retrieval.distance import BLAS, Ranked, features, ranked_exactly, rounding_slack, top_matches

# Rows fitted for the axis: its direction only decides how much is pruned, never the answer.
AXIS_SAMPLE = 4096
# Rows either side of the queries on the axis whose distances give the first bound, shared
# among the queries (a share profile's 11 spectra lie close together on the axis).
NEIGHBOURS = 256
# Reach widened by this share of the bound and of the positions' magnitude: rounding moves a
# float64 distance or a 19-term dot product by < 30 ulps (~7e-15), widening by 1e-9 keeps ~10⁵
# times that margin and costs no measurable rows.
ROUNDING = 1e-9


class AxisIndex:
    """Keys, features (m, k - 1), squared norms and positions of stored rows, sorted by their
    position along the rows' principal axis, and which rows are still stored (``alive``: a
    deleted row stays in the arrays, unanswered, until the index is built again). Immutable once
    built: readers share it unlocked, and :meth:`without` makes another."""

    def __init__(self, keys: np.ndarray, stored: np.ndarray, squared: np.ndarray) -> None:
        self.axis = principal_axis(stored)
        position = stored @ self.axis if len(stored) else np.zeros(0)
        order = np.argsort(position, kind="stable")
        self.keys, self.features, self.squared = keys[order], stored[order], squared[order]
        self.position = position[order]
        self.squared_max = float(squared.max()) if len(squared) else 0.0
        self.alive = np.ones(len(keys), dtype=bool)
        self.dead = 0  # rows deleted since the index was built

    def __len__(self) -> int:
        return len(self.keys)

    def without(self, keys: np.ndarray) -> "AxisIndex":
        """This index with the rows of ``keys`` (any not in it ignored) no longer answered; the
        arrays are shared, only the liveness is new."""
        other = copy.copy(self)
        other.alive = self.alive & ~np.isin(self.keys, keys)
        other.dead = len(self) - int(np.count_nonzero(other.alive))
        return other

    def live(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(keys, features, squared norms) of the rows still stored, in the index's order."""
        return self.keys[self.alive], self.features[self.alive], self.squared[self.alive]

    def nearest(self, queries: np.ndarray, top: int, last: int, stale: np.ndarray | None = None) -> Ranked:
        """The ``top`` rows still stored with keys ≤ ``last`` and not in ``stale`` nearest any of
        one (k,) or (n, k) query spectra, ranked as :func:`top_matches` ranks them over all such
        rows in key order; rows given by key.

        Each query measures, by one matrix-vector product, the rows within reach of it on the
        axis, and keeps those rounding could place within reach of it in distance: a row in the
        top is within reach of the query it is nearest to. The few kept are then ranked exactly.
        (A share profile's 11 spectra lie apart on the axis: one product of all 11 over every
        row within reach of any measured several times more.)"""
        if len(self) == 0:
            return merged([], top)
        asked = features(queries)
        answerable = self.alive if stale is None or len(stale) == 0 else self.alive & ~np.isin(self.keys, stale)
        reach = self._reach(asked, top, last, answerable)
        if not np.isfinite(reach):  # too few rows known: every one is ranked
            rows = np.flatnonzero(answerable & (self.keys <= last))
            ranked = top_matches(queries, self.features[rows], self.squared[rows], top, ties=self.keys[rows])
            return ranked._replace(rows=self.keys[rows[ranked.rows]])
        within = []
        with BLAS.limit(limits=1, user_api="blas"):
            for query, centre in zip(asked, asked @ self.axis, strict=True):
                start = int(np.searchsorted(self.position, centre - reach, side="left"))
                end = int(np.searchsorted(self.position, centre + reach, side="right"))
                rows = slice(start, end)
                approximate = self.squared[rows] - 2 * (self.features[rows] @ query) + query @ query
                near = reach**2 + rounding_slack(self.squared_max, query @ query)
                within.append(start + np.flatnonzero(approximate <= near))
        rows = np.unique(np.concatenate(within))
        rows = rows[answerable[rows] & (self.keys[rows] <= last)]
        ranked = ranked_exactly(asked, self.features, rows, self.keys[rows], top)
        return ranked._replace(rows=self.keys[ranked.rows])

    def _reach(self, asked: np.ndarray, top: int, last: int, answerable: np.ndarray) -> float:
        """How far along the axis a row in the top can lie from the nearest query: the
        ``top``-th distance among the queries' neighbours on the axis, widened past rounding;
        infinite where too few rows are known (every row is then ranked)."""
        centres = np.searchsorted(self.position, asked @ self.axis)
        span = max(top, NEIGHBOURS // len(centres))
        near = np.unique(np.concatenate([np.arange(max(0, c - span), min(len(self), c + span)) for c in centres]))
        near = near[answerable[near] & (self.keys[near] <= last)]
        if not 0 < top <= len(near):
            return np.inf
        each = np.stack([np.linalg.norm(self.features[near] - query, axis=1) for query in asked])
        bound = np.partition(each.min(axis=0), top - 1)[top - 1]
        largest = max(np.sqrt(self.squared_max), float(np.abs(asked).sum(axis=1).max()))
        return bound * (1 + ROUNDING) + ROUNDING * largest


def principal_axis(stored: np.ndarray) -> np.ndarray:
    """The unit direction of largest spread of (m, d) rows, fitted on an evenly strided sample;
    d zeros for no rows, a coordinate axis where every sampled row is the same."""
    if len(stored) == 0:
        return np.zeros(stored.shape[1] if stored.ndim == 2 else 0)
    sample = stored[:: max(1, len(stored) // AXIS_SAMPLE)]
    centred = sample - sample.mean(axis=0)
    axis = np.linalg.svd(centred, full_matrices=False)[2][0] if np.any(centred) else np.eye(stored.shape[1])[0]
    return np.ascontiguousarray(axis)


def merged(parts: list[Ranked], top: int) -> Ranked:
    """The ``top`` first of several rankings whose rows are keys: by distance, then key (the
    stable order of rows kept in key order)."""
    if not parts:
        return Ranked(np.zeros(0, dtype=np.int64), np.zeros(0), np.zeros(0, dtype=np.int64))
    keys = np.concatenate([part.rows for part in parts])
    distance = np.concatenate([part.distances for part in parts])
    query = np.concatenate([part.queries for part in parts])
    order = np.lexsort((keys, distance))[:top]
    return Ranked(keys[order], distance[order], query[order])
