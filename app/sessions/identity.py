"""Who a session's person is: the stored people nearest the body fitted to its views.

The body fitted to a session's views (decision 039) is known where the views saw it and
uncertain elsewhere: its shape coefficients come with a posterior covariance. Where the stored
shapes have bodies (their person's shape coefficients, :class:`app.retrieval.store.StoredBody`),
each is ranked by the Mahalanobis distance of its coefficients from the fit's, under the fit's
covariance plus the stored body's own spread: what the views did not see does not count against
anyone (:func:`ranked_by_shape`). Otherwise the fitted body's closed spectrum is ranked against
the stored closed spectra (ShapeDNA; a closed surface's spectrum barely moves with pose), which
forgets that uncertainty (:func:`ranked_people` over the store's matches).

One answer per person (label): their nearest stored shape and its distance, and a confidence: a
softmax over the people ranked of −d²/2τ², τ fitted on calibration sessions (``models/body.npz``,
one per ranking) so that the first person's confidence says how often the first is right. By
shape, the person scanned may be no one stored: the softmax holds one more alternative, "not
stored", at the distance no calibration person's own stored shape was farther than, so that a
session of someone not stored is not answered with full confidence for the nearest stranger.
"""

from dataclasses import dataclass

import numpy as np
from scipy.linalg import solve_triangular

from app.inference.bodyfit import BodyBasis, FittedBody
from app.retrieval.store import Match, ShapeStore, StoredBodies

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
    return ranked_rows([(m.record.label, m.record.id, m.distance) for m in matches], top, scale)


def shape_distances(fitted: FittedBody, bodies: StoredBodies) -> np.ndarray:
    """(n,) each stored body's Mahalanobis distance from the fitted coefficients, under the fit's
    posterior covariance plus the stored body's spread² on every coefficient. The posterior is
    not inflated by the vertices' calibrated factor: that drowned the spread's floor and lost
    first places at 3–5 views (decision 039)."""
    found = np.empty(len(bodies.ids))
    for spread in np.unique(bodies.spread):  # one factorization per kind of stored body
        rows = np.flatnonzero(bodies.spread == spread)
        factor = np.linalg.cholesky(fitted.covariance + spread**2 * np.eye(len(fitted.coefficients)))
        whitened = solve_triangular(factor, (bodies.coefficients[rows] - fitted.coefficients).T, lower=True)
        found[rows] = np.sqrt((whitened**2).sum(axis=0))
    return found


def ranked_by_shape(
    fitted: FittedBody, bodies: StoredBodies, top: int, scale: float, unknown: float
) -> list[Candidate]:
    """The ``top`` people with stored bodies, nearest the fitted body by :func:`shape_distances`,
    with the confidence of a softmax of −d²/2``scale``² over every person stored with a body and
    someone not stored, at distance ``unknown``."""
    distance = shape_distances(fitted, bodies)
    return ranked_rows(list(zip(bodies.labels, bodies.ids, distance.tolist(), strict=True)), top, scale, unknown)


@dataclass(frozen=True)
class ShapeRanking:
    """The stored shapes nearest a fitted body by shape, nearest first, as (id, label, distance);
    the people among them, one candidate each with its confidence; the ranking's warnings."""

    shapes: list[tuple[str, str, float]]
    people: list[Candidate]
    warnings: list[str]


def shape_ranking(store: ShapeStore, basis: BodyBasis, fitted: FittedBody, top: int) -> ShapeRanking | None:
    """The ``top`` stored shapes and people nearest ``fitted`` by shape (:func:`ranked_by_shape`,
    someone not stored at the distance a fit as good as this one allows), warned where even the
    nearest is farther than stored people's own scans lie and where stored shapes have no body to
    rank; None where none has (they are then ranked by the fitted body's spectrum). Blocking: it
    reads every stored body."""
    bodies = store.bodies()
    if not bodies.ids:
        return None
    unknown = basis.unknown_for(fitted.residual_m)
    distance = shape_distances(fitted, bodies)
    rows = list(zip(bodies.labels, bodies.ids, distance.tolist(), strict=True))
    people = ranked_rows(rows, top, basis.shape_identity_scale, unknown)
    order = np.argsort(distance, kind="stable")[:top]  # ties (one person's shapes at rest) as `people` breaks them
    shapes = [(bodies.ids[i], bodies.labels[i], float(distance[i])) for i in order]
    warnings = unknown_warning(people[0] if people else None, unknown)
    unranked = store.count() - len(bodies.ids)
    if unranked:
        warnings.append(f"{unranked} stored shapes have no body (none fitted their scan) and are not ranked")
    return ShapeRanking(shapes, people, warnings)


def unknown_warning(first: Candidate | None, unknown: float) -> list[str]:
    """A warning when even the nearest stored person is farther than ``unknown``."""
    if first is None or first.distance <= unknown:
        return []
    return [
        f"no stored person is near (the nearest at {first.distance:.1f}, stored people's own scans stay within "
        f"{unknown:.1f}): the person scanned is probably not stored"
    ]


def ranked_rows(
    rows: list[tuple[str, str, float]], top: int, scale: float, unknown: float = float("inf")
) -> list[Candidate]:
    """(label, shape id, distance) rows as one candidate per label at its nearest row, nearest
    first, each with the softmax confidence over all the labels (and, at a finite ``unknown``
    distance, someone not stored)."""
    nearest: dict[str, tuple[str, str, float]] = {}
    for row in sorted(rows, key=lambda row: row[2]):
        nearest.setdefault(row[0], row)
    people = list(nearest.values())
    if not people:
        return []
    distance = np.array([row[2] for row in people] + ([unknown] if np.isfinite(unknown) else []))
    logits = -0.5 * (distance / scale) ** 2
    weights = np.exp(logits - logits.max())
    confidence = weights / weights.sum()
    return [
        Candidate(label, shape_id, float(d), float(c))
        for (label, shape_id, d), c in zip(people[:top], confidence[:top], strict=True)
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
