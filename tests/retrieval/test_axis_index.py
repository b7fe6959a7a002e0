"""The axis index measures only rows within reach of the query along the principal axis: its
answer must still be, to the bit, the stable sort of every exact distance over the rows a
snapshot sees, and the copy that keeps it must stay so while rows are added."""

import numpy as np
import pytest

from app.retrieval import feature_copy
from app.retrieval.axis_index import AxisIndex, _windows
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
        reach = index._reach(query, asked, 10, len(stored))
        measured.append(sum(w.stop - w.start for w in _windows(index.position, asked @ index.axis, reach)))
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


def test_identical_rows_and_an_empty_index():
    stored = np.tile(people(1, 7), (50, 1))
    assert_ranked(index_of(stored).nearest(stored[0], 5, 50), truth(stored[0], stored, 5))
    empty = AxisIndex(np.zeros(0, dtype=np.int64), np.zeros((0, 0)), np.zeros(0))
    assert len(empty.nearest(stored[0], 5, 10).rows) == 0


class Rows:
    """A RowSource over an array whose rows are added in batches (keys 1…n)."""

    def __init__(self, stored: np.ndarray) -> None:
        self.stored, self.visible = stored, 0

    def version(self) -> int:
        return 0

    def last(self) -> int:
        return self.visible

    def spectra_after(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        return np.arange(key + 1, self.visible + 1), self.stored[key : self.visible]


def test_the_copy_ranks_exactly_while_rows_arrive_and_its_index_is_rebuilt(monkeypatch):
    """Rows added past the index are scanned beside it until they are many, then indexed again;
    answers at every step (and for a snapshot older than the copy) are the exact ones."""
    monkeypatch.setattr(feature_copy, "TAIL_ROWS", 300)
    stored = people(4_000, 8)
    queries = people(6, 9)
    copy, rows = FeatureCopy(), Rows(stored)
    rebuilt = 0
    for visible in (1, 2, 250, 700, 701, 1_500, 2_600, 4_000):
        rows.visible = visible
        before = len(copy._index)
        for query in (queries[visible % 6], queries[:3]):
            assert_ranked(copy.nearest(rows, query, 10), truth(query, stored, 10, visible))
        rebuilt += len(copy._index) != before
        old = Rows(stored)
        old.visible = visible // 2  # another transaction's older snapshot
        assert_ranked(copy.nearest(old, queries[0], 10), truth(queries[0], stored, 10, visible // 2))
    assert rebuilt >= 2
