"""Who a session's person is: the stored people nearest the body fitted to its views.

The store holds complete bodies' closed spectra (ShapeDNA), a person in several poses. A
session's union is an open surface, whose spectrum is of another kind; the body fitted to its
views (decision 039) is a closed body whose spectrum compares with the stored shapes' (a closed
surface's spectrum barely moves with pose). One answer per person (label): their nearest stored
shape and its distance, and a confidence: a softmax over the people ranked of −d²/2τ², τ fitted
on calibration sessions (``models/body.npz``) so that the first person's confidence says how
often the first is right.
"""

from dataclasses import dataclass

import numpy as np

from app.retrieval.store import Match

SHAPES_PER_PERSON = 10  # stored shapes asked for per person answered: a person is stored in several poses
CLEARLY_AHEAD = 0.5  # a first person less confident than this is no identification: the answer says so


@dataclass(frozen=True)
class Candidate:
    label: str
    shape_id: str
    distance: float
    confidence: float


def ranked_people(matches: list[Match], top: int, scale: float) -> list[Candidate]:
    """The ``top`` people of ``matches`` (nearest first), each at their nearest stored shape, with
    the confidence of a softmax of −d²/2``scale``² over every person the matches hold."""
    nearest: dict[str, Match] = {}
    for match in sorted(matches, key=lambda m: m.distance):
        nearest.setdefault(match.record.label, match)
    people = list(nearest.values())
    if not people:
        return []
    distance = np.array([m.distance for m in people])
    logits = -0.5 * (distance / scale) ** 2
    weights = np.exp(logits - logits.max())
    confidence = weights / weights.sum()
    return [
        Candidate(m.record.label, m.record.id, float(m.distance), float(c))
        for m, c in zip(people[:top], confidence[:top], strict=True)
    ]


def ahead_warning(first: float | None) -> list[str]:
    """A warning when the first person's confidence (None: none ranked, or no calibrated
    confidence) says they are not clearly ahead of the others."""
    if first is None or first >= CLEARLY_AHEAD:
        return []
    return [
        f"the first person is not clearly ahead (confidence {first:.2f}): the views leave several stored people "
        "about as near; this is not an identification"
    ]
