"""Identity from a session, as ``/v1/sessions/{id}/identity`` ranks it and as the service ranked
the session's union before: scored against the seed database, where Test C's people are stored in
ten poses of the build's (none the session's).

A ranking here is a person's best ShapeDNA distance over their stored shapes
(:func:`app.retrieval.distance.distances`, the store's own), for every person of the gallery; the
confidence is :func:`app.sessions.identity.ranked_people`'s softmax, its scale τ the one that
makes the true person most likely over the calibration sessions.
"""

from pathlib import Path

import numpy as np

from app.retrieval.distance import distances
from app.retrieval.seed import SEED_FILE
from app.retrieval.store import Match, ShapeRecord

SCALES = np.geomspace(0.005, 2.0, 200)  # the τ tried


class Gallery:
    """Stored people's closed spectra: the seed database and, for calibration, people added."""

    def __init__(self, labels: np.ndarray, spectra: np.ndarray) -> None:
        self.labels, self.spectra = labels, spectra

    @classmethod
    def seed(cls, models: Path) -> "Gallery":
        data = np.load(models / SEED_FILE)
        return cls(np.asarray([str(label) for label in data["labels"]]), data["spectra"].astype(np.float64))

    def with_people(self, labels: list[str], spectra: np.ndarray) -> "Gallery":
        return Gallery(np.concatenate([self.labels, labels]), np.concatenate([self.spectra, spectra]))

    def matches(self, spectrum: np.ndarray, count: int) -> list[Match]:
        """The ``count`` stored shapes nearest ``spectrum``, as the store answers them."""
        found = distances(spectrum, self.spectra)
        nearest = np.argsort(found, kind="stable")[:count]
        return [Match(ShapeRecord(str(i), str(self.labels[i]), "gallery", [], ""), float(found[i])) for i in nearest]

    def person_distances(self, spectrum: np.ndarray) -> dict[str, float]:
        """Each stored person's distance: their nearest stored shape's."""
        found = distances(spectrum, self.spectra)
        best: dict[str, float] = {}
        for label, distance in zip(self.labels, found, strict=True):
            best[label] = min(best.get(label, np.inf), float(distance))
        return best


def rank_of(person_distances: dict[str, float], label: str) -> int:
    """Where ``label`` ranks (0: first) among the people by distance."""
    truth = person_distances[label]
    return sum(distance < truth for distance in person_distances.values())


def fitted_scale(rows: list[tuple[dict[str, float], str]]) -> float:
    """The τ under which the true people are most likely: rows of (person distances, truth)."""

    def likelihood(scale: float) -> float:
        total = 0.0
        for person_distances, label in rows:
            distance = np.fromiter(person_distances.values(), float)
            logits = -0.5 * (distance / scale) ** 2
            total += -0.5 * (person_distances[label] / scale) ** 2 - (
                logits.max() + np.log(np.exp(logits - logits.max()).sum())
            )
        return total

    return float(SCALES[int(np.argmax([likelihood(scale) for scale in SCALES]))])
