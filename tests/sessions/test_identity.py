"""One answer per person, nearest first, with a softmax confidence checked by hand."""

import math

import pytest

from app.retrieval.store import Match, ShapeRecord
from app.sessions.identity import CLEARLY_AHEAD, ahead_warning, ranked_people


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
