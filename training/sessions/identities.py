"""Identity from a session, as ``/v1/sessions/{id}/identity`` ranks it and as the service ranked
the session before: scored against the seed database, where Test C's people are stored in ten
poses of the build's (none the session's), each with their shape coefficients at rest
(``models/seed_bodies.npz``, :func:`write_seed_bodies`).

A ranking here is a person's best distance over their stored shapes, for every person of the
gallery: by shape (:func:`app.sessions.identity.shape_distances`, as served) or by the fitted
body's ShapeDNA distance (:func:`app.retrieval.distance.distances`, the store's own); the
confidence is :func:`app.sessions.identity.ranked_people`'s softmax, its scale τ the one that
makes the true person most likely over the calibration sessions.
"""

from pathlib import Path

import numpy as np

from app.contract import SEED_BODIES_FILE
from app.inference import BodyBasis, FittedBody
from app.retrieval import AT_REST_SPREAD, SEED_FILE, StoredBodies, distances, seed_bodies
from app.sessions import shape_distances

SCALES = np.geomspace(0.005, 2.0, 200)  # the τ tried


class Gallery:
    """Stored people's closed spectra and shape coefficients at rest: the seed database and, for
    calibration, people added."""

    def __init__(self, labels: np.ndarray, spectra: np.ndarray, coefficients: np.ndarray) -> None:
        self.labels, self.spectra, self.coefficients = labels, spectra, coefficients

    @classmethod
    def seed(cls, models: Path) -> "Gallery":
        data = np.load(models / SEED_FILE)
        labels = [str(label) for label in data["labels"]]
        stored = seed_bodies(models, labels)
        if stored is None:
            raise FileNotFoundError(f"{models / SEED_BODIES_FILE} is missing or lacks a seed person")
        coefficients = np.stack([body.coefficients for body in stored])
        return cls(np.asarray(labels), data["spectra"].astype(np.float64), coefficients)

    def with_people(self, labels: list[str], spectra: np.ndarray, coefficients: np.ndarray) -> "Gallery":
        return Gallery(
            np.concatenate([self.labels, labels]),
            np.concatenate([self.spectra, spectra]),
            np.concatenate([self.coefficients, coefficients]),
        )

    def bodies(self) -> StoredBodies:
        """The gallery as the store's bodies (each read at rest)."""
        ids = [str(i) for i in range(len(self.labels))]
        spread = np.full(len(self.labels), AT_REST_SPREAD)
        return StoredBodies(ids, [str(label) for label in self.labels], self.coefficients, spread)

    def shape_distances(self, fitted: FittedBody) -> dict[str, float]:
        """Each stored person's distance by shape: their nearest stored body's, as served."""
        return _per_person(self.labels, shape_distances(fitted, self.bodies()))

    def person_distances(self, spectrum: np.ndarray) -> dict[str, float]:
        """Each stored person's ShapeDNA distance: their nearest stored shape's."""
        return _per_person(self.labels, distances(spectrum, self.spectra))


def _per_person(labels: np.ndarray, found: np.ndarray) -> dict[str, float]:
    best: dict[str, float] = {}
    for label, distance in zip(labels, found, strict=True):
        best[label] = min(best.get(label, np.inf), float(distance))
    return best


def rest_coefficients(basis: BodyBasis, rest: np.ndarray) -> np.ndarray:
    """(C,) the whitened shape coefficients of a body at rest (V, 3): its least-squares projection
    on the basis (the basis is a PCA of anny's rest-pose bodies, in their frame)."""
    flat = basis.components.reshape(len(basis.components), -1).T
    return np.linalg.lstsq(flat, (rest - basis.mean).ravel(), rcond=None)[0]


def write_seed_bodies(models: Path, basis: BodyBasis) -> None:
    """``models/seed_bodies.npz``: each seed person's shape coefficients at rest, for the seed
    database's bodies (the standard build's identities, drawn again as the build draws them)."""
    from training.data.bodies import AnnySource
    from training.sessions.scans import build_identities, rest_body

    source = AnnySource()
    drawn = build_identities(source)
    coefficients = np.stack([rest_coefficients(basis, rest_body(source, row[2])) for row in drawn])
    np.savez_compressed(
        models / SEED_BODIES_FILE, labels=np.asarray([row[3] for row in drawn]), coefficients=coefficients
    )


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
