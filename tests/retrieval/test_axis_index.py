"""The axis index measures only rows within reach of the query along the principal axis: its
answer must still be, to the bit, the stable sort of every exact distance over the rows a
snapshot sees, and the copy that keeps it must stay so while rows are added."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from app.retrieval import feature_copy
from app.retrieval.axis_index import AxisIndex
from app.retrieval.distance import features, nearest_of
from app.retrieval.feature_copy import FeatureCopy


def people(count: int, seed: int) -> np.ndarray:
    """Spectra clustered as people are: 40 bodies, each resized by ~5 % and perturbed by ~2 %."""
    rng = np.random.default_rng(seed)
    bodies = np.sort(rng.uniform(1, 80, (40, 20)), axis=1) * rng.uniform(0.4, 2.5, (40, 1))
    rows = bodies[rng.integers(40, size=count)] * np.exp(rng.normal(0, 0.05, (count, 1)))
    return np.sort(rows * np.exp(rng.normal(0, 0.02, (count, 20))), axis=1)


def index_of(stored: np.ndarray) -> AxisIndex:
    keyed = features(stored)
    return AxisIndex(np.arange(1, len(stored) + 1), keyed, (keyed**2).sum(axis=1))


def truth(queries: np.ndarray, stored: np.ndarray, top: int, last: int | None = None):
    """(keys, distances, nearest query) of the top rows with keys ≤ last, from every row."""
    seen = stored[: len(stored) if last is None else last]
    distance, query = nearest_of(queries, seen)
    order = np.argsort(distance, kind="stable")[:top]
    return order + 1, distance[order], query[order]


def assert_ranked(ranked, expected) -> None:
    keys, distances, queries = expected
    np.testing.assert_array_equal(ranked.rows, keys)
    np.testing.assert_array_equal(ranked.distances, distances)
    np.testing.assert_array_equal(ranked.queries, queries)


@pytest.mark.parametrize("queries", [1, 11])
@pytest.mark.parametrize("top", [1, 10, 57])
def test_the_index_ranks_as_every_row_does(queries, top):
    stored = people(20_000, 1)
    asked = people(queries, 2) if queries == 1 else people(1, 2) * np.linspace(1.0, 0.7, queries)[:, None]
    assert_ranked(index_of(stored).nearest(asked, top, len(stored)), truth(asked, stored, top))


def test_the_index_measures_a_minority_of_clustered_rows():
    """What it is for: on people-like spectra, one query's windows hold well under half the rows
    (and the answer is the exact one, above)."""
    stored = people(20_000, 3)
    index = index_of(stored)
    measured = []
    for query in people(20, 4):
        asked = features(query)
        reach = index._reach(asked, 10, len(stored), index.alive)
        ends = np.searchsorted(index.position, (asked @ index.axis)[0] + np.array([-reach, reach]))
        measured.append(ends[1] - ends[0])
    assert np.median(measured) < 0.35 * len(stored)


def test_equal_distances_at_different_positions_are_ordered_by_key():
    """Rows at exactly the same distance on either side of the query (log 2 and log ½ are exact
    negatives) lie apart on the axis; ties must still go to the lower key."""
    rng = np.random.default_rng(5)
    stored = 2.0 ** rng.integers(-2, 3, (3_000, 20)).astype(float)
    query = np.ones(20)
    for top in (1, 10, 100, 700):
        assert_ranked(index_of(stored).nearest(query, top, len(stored)), truth(query, stored, top))


@pytest.mark.parametrize("last", [0, 1, 500, 2_999])
def test_rows_past_the_snapshot_are_not_answered(last):
    """A query whose snapshot is older than the index sees only keys up to its last, ranked as if
    the newer rows were not there (they may be nearer)."""
    stored = people(3_000, 6)
    query = stored[-1] * 1.001  # the newest row is the nearest
    assert_ranked(index_of(stored).nearest(query, 10, last), truth(query, stored, 10, last))


@settings(max_examples=60, deadline=None)
@given(
    seed=st.integers(0, 2**32 - 1),
    rows=st.integers(1, 400),
    top=st.integers(1, 60),
    queries=st.integers(1, 4),
    deleted=st.floats(0, 0.9),
    last=st.floats(0, 1),
)
def test_any_index_with_deletions_ranks_as_every_row_it_answers(seed, rows, top, queries, deleted, last):
    """Whatever the rows (some repeated, some at one point), the deleted ones, the snapshot's last
    key and the stale keys: the answer is the stable ranking of exactly the rows it may answer."""
    rng = np.random.default_rng(seed)
    stored = people(rows, seed % 1000)
    stored[rng.random(rows) < 0.1] = stored[0]  # repeated rows: ties on the axis and in distance
    gone = np.flatnonzero(rng.random(rows) < deleted) + 1
    stale = rng.choice(np.arange(1, rows + 1), size=min(rows, int(rng.integers(0, 3))), replace=False)
    seen = int(round(last * rows))
    index = index_of(stored).without(gone)
    asked = people(1, seed % 997) * np.linspace(1.0, 0.8, queries)[:, None]
    answerable = [k for k in range(1, seen + 1) if k not in set(gone) | set(stale)]
    expected_rows = {k: stored[k - 1] for k in answerable}
    keys = np.array(sorted(expected_rows), dtype=np.int64)
    spectra_ = np.array([expected_rows[k] for k in keys]).reshape(len(keys), stored.shape[1])
    distance, nearest = nearest_of(asked, spectra_) if len(keys) else (np.zeros(0), np.zeros(0, dtype=np.int64))
    order = np.argsort(distance, kind="stable")[:top]
    assert_ranked(index.nearest(asked, top, seen, stale), (keys[order], distance[order], nearest[order]))


def test_identical_rows_and_an_empty_index():
    stored = np.tile(people(1, 7), (50, 1))
    assert_ranked(index_of(stored).nearest(stored[0], 5, 50), truth(stored[0], stored, 5))
    empty = AxisIndex(np.zeros(0, dtype=np.int64), np.zeros((0, 0)), np.zeros(0))
    assert len(empty.nearest(stored[0], 5, 10).rows) == 0


class Table:
    """Rows as SQLite keeps them (a new row's key one above the greatest stored, so the newest
    row's key is given again once it is deleted), with a deletion log; ``snapshot()`` freezes
    what one transaction sees, as a RowSource. Counts the full reads. ``prune`` forgets all but
    the last deletions of the log, as the stores do."""

    def __init__(self) -> None:
        self.rows: dict[int, np.ndarray] = {}
        self.log: list[int] = []
        self.pruned = 0  # entries of the log forgotten, from the front
        self.full_reads = 0

    def add(self, spectra: np.ndarray) -> None:
        for spectrum in spectra:
            self.rows[max(self.rows, default=0) + 1] = spectrum

    def delete(self, key: int) -> None:
        del self.rows[key]
        self.log.append(key)

    def prune(self, kept: int) -> None:
        self.pruned = max(self.pruned, len(self.log) - kept)

    def snapshot(self) -> "Snapshot":
        return Snapshot(self, dict(self.rows), list(self.log), self.pruned)


class Snapshot:
    def __init__(self, table: Table, rows: dict[int, np.ndarray], log: list[int], pruned: int = 0) -> None:
        self.table, self.rows, self.log, self.pruned = table, rows, log, pruned

    def version(self) -> int:
        return 0

    def last(self) -> int:
        return max(self.rows, default=0)

    def deletions(self) -> int:
        return 3 * len(self.log)

    def deleted_after(self, position: int) -> tuple[np.ndarray, np.ndarray]:
        """Positions with gaps, as a rolled-back PostgreSQL deletion leaves them (3 per entry);
        the pruned entries are gone."""
        first = max(position // 3, self.pruned)
        return 3 * np.arange(first + 1, len(self.log) + 1), np.array(self.log[first:], dtype=np.int64)

    def forgotten(self) -> int:
        """The oldest kept entry's position less one (the gap before it counts as forgotten)."""
        return 3 * (self.pruned + 1) - 1 if self.pruned else 0

    def spectra_after(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        self.table.full_reads += key == 0
        keys = sorted(k for k in self.rows if k > key)
        return np.array(keys, dtype=np.int64), np.array([self.rows[k] for k in keys]).reshape(len(keys), -1)

    def truth(self, query: np.ndarray, top: int, rows: dict[int, np.ndarray] | None = None):
        """(keys, distances, nearest query) of the top of ``rows`` (default: this snapshot's)."""
        rows = self.rows if rows is None else rows
        keys = np.array(sorted(rows), dtype=np.int64)
        distance, nearest = nearest_of(query, np.array([rows[k] for k in keys]).reshape(len(keys), -1))
        order = np.argsort(distance, kind="stable")[:top]
        return keys[order], distance[order], nearest[order]


def test_the_copy_ranks_exactly_while_rows_arrive_and_go(monkeypatch):
    """Rows added past the index are scanned beside it and deleted ones carried unanswered until
    they are many, then indexed again; a deletion is read from the log, except the newest row's
    (its key may come back): answers at every step are the exact ones, and for a snapshot older
    than the copy's rows, a prefix of them."""
    monkeypatch.setattr(feature_copy, "TAIL_ROWS", 300)
    pool, queries = people(6_000, 8), people(6, 9)
    rng = np.random.default_rng(10)
    table, copy = Table(), FeatureCopy()
    table.add(pool[:1])
    rebuilt = reloads = 0
    for step in range(40):
        before, reads = copy._index, table.full_reads
        if step % 4 == 3:  # the newest row: SQLite gives its key to the next row
            table.delete(max(table.rows))
            reloads += 1
        elif step % 4 == 2:
            for key in rng.choice(sorted(table.rows)[:-1], size=min(len(table.rows) - 1, 40), replace=False):
                table.delete(int(key))
        table.add(pool[rng.integers(len(pool), size=int(rng.integers(1, 400)))])
        seen = table.snapshot()
        for query in (queries[step % 6], queries[:3]):
            assert_ranked(copy.nearest(seen, query, 10), seen.truth(query, 10))
        assert table.full_reads - reads == (step % 4 == 3 or step == 0), step  # the log, not a re-read
        rebuilt += copy._index is not before and len(copy._index) != len(before)
        older = Snapshot(table, {k: v for k, v in seen.rows.items() if k <= seen.last() // 2}, seen.log)
        assert_ranked(copy.nearest(older, queries[0], 10), older.truth(queries[0], 10))
    assert rebuilt >= 3 and reloads == 10


def test_a_snapshot_older_than_a_deletion_is_not_answered_the_deleted_rows():
    """A query that took its snapshot before a deletion another query applied first: the rows it
    sees less the deleted ones, and never a row whose key SQLite gave again."""
    table, copy = Table(), FeatureCopy()
    table.add(people(500, 11))
    query = table.rows[250] * 1.001
    copy.nearest(table.snapshot(), query, 5)
    old = table.snapshot()
    for key in (250, 251, 17):
        table.delete(key)
    newest = max(table.rows)
    table.add(people(3, 12))  # keys above the newest: nothing given again yet
    copy.nearest(table.snapshot(), query, 5)
    expected = {k: v for k, v in old.rows.items() if k in table.rows}
    assert_ranked(copy.nearest(old, query, 10), old.truth(query, 10, expected))
    # The newest row deleted and its key given again: the copy reads everything; a snapshot older
    # than that is read whole (the copy no longer knows what went before it).
    table.delete(max(table.rows))
    table.add(people(1, 13) * 0 + query)  # the query itself, under a key the old snapshot knows otherwise
    copy.nearest(table.snapshot(), query, 5)
    assert_ranked(copy.nearest(old, query, 10), old.truth(query, 10))
    assert newest < max(table.rows)


def test_a_log_pruned_past_the_copy_s_last_read_is_not_trusted(monkeypatch):
    """Deletions within what the log keeps are read from it; a copy that last read the log before
    its oldest kept deletion reads every row again; answers exact either way. The copy's own log
    keeps as many: a snapshot older than the deletions it forgot is read whole."""
    monkeypatch.setattr(feature_copy, "DELETIONS_KEPT", 4)
    table, copy = Table(), FeatureCopy()
    table.add(people(400, 15))
    query = table.rows[200] * 1.001
    near = [int(key) for key in table.snapshot().truth(query, 15)[0] if key != max(table.rows)]
    copy.nearest(table.snapshot(), query, 5)
    reads = table.full_reads
    for key in near[:3]:  # the query's nearest rows, one query between deletions
        table.delete(key)
        table.prune(4)
        seen = table.snapshot()
        assert_ranked(copy.nearest(seen, query, 10), seen.truth(query, 10))
    assert table.full_reads == reads  # read from the log
    for key in near[3:9]:  # more than the log keeps, no query between
        table.delete(key)
    table.prune(4)
    seen = table.snapshot()
    assert_ranked(copy.nearest(seen, query, 10), seen.truth(query, 10))
    assert table.full_reads == reads + 1  # the log no longer held what the copy had not read
    older = table.snapshot()
    for key in near[9:14]:  # one query each: the copy's log outgrows what it keeps
        table.delete(key)
        table.prune(4)
        copy.nearest(table.snapshot(), query, 5)
    assert len(copy._log_positions) == 4 and table.full_reads == reads + 1
    # Five deletions since ``older``, the copy remembering four: read whole, those five its nearest.
    assert_ranked(copy.nearest(older, query, 5), older.truth(query, 5))
    assert set(copy.nearest(older, query, 5).rows.tolist()) == set(near[9:14])
