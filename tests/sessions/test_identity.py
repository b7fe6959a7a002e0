"""One answer per person, nearest first, with a softmax confidence checked by hand; by shape, the
Mahalanobis distance under the fit's uncertainty, checked by hand."""

import math

import numpy as np
import pytest

from app.inference.bodyfit import BodyBasis, FittedBody
from app.retrieval.store import Match, ShapeRecord, SQLiteStore, StoredBodies, StoredBody
from app.sessions.identity import (
    CLEARLY_AHEAD,
    ahead_warning,
    ranked_by_shape,
    ranked_people,
    ranked_rows,
    shape_distances,
    shape_ranking,
    unknown_warning,
)


def match(label: str, shape: str, distance: float) -> Match:
    return Match(ShapeRecord(shape, label, "test", [], ""), distance)


def test_each_person_answers_once_at_their_nearest_shape():
    matches = [match("ann", "a1", 0.3), match("bob", "b1", 0.5), match("ann", "a2", 0.1), match("bob", "b2", 0.9)]
    people = ranked_people(matches, top=5, scale=1.0)
    assert [(p.label, p.shape_id, p.distance) for p in people] == [("ann", "a2", 0.1), ("bob", "b1", 0.5)]


def test_the_confidence_is_a_softmax_of_the_squared_distances():
    people = ranked_people([match("ann", "a", 0.0), match("bob", "b", 1.0)], top=2, scale=1.0)
    ann = 1.0 / (1.0 + math.exp(-0.5))
    assert people[0].confidence == pytest.approx(ann) and people[1].confidence == pytest.approx(1.0 - ann)


def test_a_first_person_not_clearly_ahead_is_warned_about():
    close = ranked_people([match("ann", "a", 0.50), match("bob", "b", 0.51), match("cy", "c", 0.52)], top=3, scale=1.0)
    assert close[0].confidence < CLEARLY_AHEAD and ahead_warning(close[0].confidence)
    clear = ranked_people([match("ann", "a", 0.0), match("bob", "b", 5.0)], top=2, scale=1.0)
    assert clear[0].confidence > CLEARLY_AHEAD and not ahead_warning(clear[0].confidence)
    assert ranked_people([], top=3, scale=1.0) == [] and not ahead_warning(None)


def test_by_shape_what_the_views_left_uncertain_counts_less():
    """Hand-checked Mahalanobis distances: a stored body 2 away along a coefficient the fit knows
    to ±2 is at 1; one 0.5 away along a coefficient known to ±0.1 is at 5, so it ranks second
    though nearer; a stored body's spread widens its own distance: 2 / √(4 + 1.5²) = 0.8."""
    fitted = FittedBody(np.array([1.0, -1.0]), np.diag([4.0, 0.01]), points=1000, residual_m=0.005)
    bodies = StoredBodies(
        ["a", "b", "c"],
        ["ann", "bob", "cy"],
        np.array([[3.0, -1.0], [1.0, -0.5], [3.0, -1.0]]),
        np.array([0.0, 0.0, 1.5]),
    )
    np.testing.assert_allclose(shape_distances(fitted, bodies), [1.0, 5.0, 0.8], rtol=1e-9)
    people = ranked_by_shape(fitted, bodies, top=3, scale=1.0, unknown=float("inf"))
    assert [p.label for p in people] == ["cy", "ann", "bob"] and [p.shape_id for p in people] == ["c", "a", "b"]
    assert sum(p.confidence for p in people) == pytest.approx(1.0)


def test_someone_not_stored_takes_a_share_of_the_confidence_and_is_named_when_nearest():
    """With "not stored" at distance 1: people at 0 and 1 get e⁰ and e^-½ against e^-½ more; a
    session whose nearest stored person is at 3 is said to be probably of someone not stored."""
    people = ranked_rows([("ann", "a", 0.0), ("bob", "b", 1.0)], top=2, scale=1.0, unknown=1.0)
    total = 1 + 2 * math.exp(-0.5)
    assert [p.confidence for p in people] == pytest.approx([1 / total, math.exp(-0.5) / total])
    far = ranked_rows([("ann", "a", 3.0)], top=1, scale=1.0, unknown=1.0)
    assert far[0].confidence == pytest.approx(math.exp(-4.5) / (math.exp(-4.5) + math.exp(-0.5)))
    assert "probably not stored" in unknown_warning(far[0], 1.0)[0] and not unknown_warning(people[0], 1.0)


def test_a_store_is_ranked_by_shape_shape_by_shape_and_person_by_person(tmp_path):
    """Stored bodies at hand-checked distances 1, 3 and 2 (an identity covariance) for two people,
    one shape stored without a body: the shapes come nearest first, each person once at their
    nearest, the shape without a body counted in a warning; a store without bodies answers None."""
    store = SQLiteStore(tmp_path / "shapes.sqlite")
    bodies = [StoredBody(np.array(c), 0.0) for c in ([1.0, 0.0], [0.0, 3.0], [0.0, -2.0])]
    store.add_many(["ann", "ann", "bob"], np.ones((3, 4)), "test", bodies)
    basis = BodyBasis(np.zeros((1, 3)), np.zeros((2, 1, 3)), np.ones((1, 1)), fit_residual_m=0.003)
    fitted = FittedBody(np.zeros(2), np.eye(2), points=1000, residual_m=0.003)
    assert shape_ranking(SQLiteStore(tmp_path / "empty.sqlite"), basis, fitted, top=5) is None
    store.add("cy", np.ones(4), "test")
    ranking = shape_ranking(store, basis, fitted, top=5)
    assert [label for _, label, _ in ranking.shapes] == ["ann", "bob", "ann"]
    assert [distance for _, _, distance in ranking.shapes] == pytest.approx([1.0, 2.0, 3.0])
    assert [p.label for p in ranking.people] == ["ann", "bob"]
    assert [p.distance for p in ranking.people] == pytest.approx([1.0, 2.0])
    store.add_many(["bob"], np.ones((1, 4)), "test", [StoredBody(np.array([0.0, -2.0]), 0.0)])  # a tie
    tied = shape_ranking(store, basis, fitted, top=5)
    assert [shape_id for shape_id, label, _ in tied.shapes if label == "bob"][0] == tied.people[1].shape_id
    assert ranking.warnings == ["1 stored shapes have no body (none fitted their scan) and are not ranked"]
