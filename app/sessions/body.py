"""A session's body: the rest-pose body fitted to its views' points and places, and its measurements.

Registered views are fitted in one frame and pose as they came; views in their own frames once
aligned (:func:`app.sessions.aligned.aligned_views`), or, where they do not come together (the
person moved between them), each in a pose and frame of its own, one shape for all. A spread of
the views' points, drawn by area so that the fine mesh of a face or a hand does not outweigh the
back, is fitted (:func:`app.inference.bodyfit.fit_body`); the measurements are taken on the fitted body,
each with an interval from bodies drawn from the fit's posterior (scaled as the calibration on
anny sessions found, and widened where the fit holds worse than the calibration fits), and only
where the session saw the parts a measurement rests on.
"""

from dataclasses import dataclass

import numpy as np

from app.contract import INTERVAL_Z
from app.geometry.descriptors import Places
from app.geometry.placing import Part
from app.inference.bodyfit import BodyBasis, FittedBody, NotEnoughSeen, fit_body
from app.inference.correspondence import CorrespondenceModel
from app.inference.measurements import MEASUREMENTS, Measurer, supported
from app.retrieval.store import StoredBody
from app.sessions.aligned import aligned_views
from app.sessions.fused import View, view_of_part
from app.sessions.session import SessionView

FIT_POINTS = 4000  # the points a fit reads, which set its cost
MAX_POSES = 8  # views fitted each in a pose of its own, at most: each adds 96 unknowns to the fit
MAX_RESIDUAL_M = 0.05  # a fit whose points stay further at the median is no body (a ball's stay far beyond)
SAMPLES = 16  # posterior bodies an interval is read from
SEEN = 0.3  # a body part whose covered share is below this was not seen enough to measure on
SEED = 0  # the draws are fixed: one session, one answer


class NoBodyFits(ValueError):
    """Views that no body fits: in their own frames, not brought together and too many to fit
    apart, or too far from the best body."""


@dataclass(frozen=True)
class Measurement:
    name: str
    value: float
    lower: float
    upper: float


@dataclass(frozen=True)
class SessionBody:
    """The fitted body (its rest-pose vertices and each one's σ, m), its measurements and those
    it leaves out with why, and the fit."""

    vertices: np.ndarray
    sigma: np.ndarray
    measurements: list[Measurement]
    not_measured: dict[str, str]
    fitted: FittedBody


def fitted_views(
    basis: BodyBasis, template: np.ndarray, geometry: list[View], places: list[np.ndarray], registered: bool
) -> FittedBody:
    """The body fitted to views (their geometry and each point's place on the rest-pose
    ``template``): ``registered``, in one frame and pose as they came; otherwise brought into one
    frame through their places where they come together, else each fitted in a pose and frame of
    its own (up to MAX_POSES views). A spread of FIT_POINTS of their points, drawn by area."""
    poses = None
    if not registered and len(geometry) > 1:
        moved = aligned_views(geometry, places)
        if moved is not None:
            geometry = moved
        elif len(geometry) <= MAX_POSES:
            poses = np.concatenate([np.full(len(view.points), number) for number, view in enumerate(geometry)])
        else:
            raise NoBodyFits(
                f"the views could not be brought into one frame through their places, and more than {MAX_POSES} "
                "cannot each be fitted in a pose of their own"
            )
    points = np.concatenate([view.points for view in geometry])
    placed = np.concatenate(places)
    mass = np.concatenate([view.mass for view in geometry])
    chosen = np.arange(len(points))
    if len(points) > FIT_POINTS:
        chosen = np.random.default_rng(SEED).choice(len(points), FIT_POINTS, replace=False, p=mass / mass.sum())
    fitted = fit_body(basis, points[chosen], placed[chosen], template, None if poses is None else poses[chosen])
    if fitted.residual_m > MAX_RESIDUAL_M:
        raise NoBodyFits(
            f"the views do not fit a body: their points stay {1000 * fitted.residual_m:.0f} mm from the best one "
            f"at the median (at most {1000 * MAX_RESIDUAL_M:.0f})"
        )
    return fitted


def stored_body(
    basis: BodyBasis,
    template: np.ndarray,
    correspondence: CorrespondenceModel,
    part: Part,
    places: Places | None = None,
) -> StoredBody | None:
    """The body a stored whole-body scan (its ``part``, placed on the rest-pose ``template`` by
    ``places`` a worker computed, else here) keeps for identity: the shape fitted to it (in the
    pose it was scanned in, which leaks into the shape: ``basis.posed_spread``), or None where no
    body fits it (not a person, too little of one)."""
    placed = correspondence.place(part, places).position  # no region: the fit reads the places alone
    try:
        fitted = fitted_views(basis, template, [view_of_part(part)], [placed], registered=True)
    except (NotEnoughSeen, NoBodyFits):
        return None
    return StoredBody(fitted.coefficients, basis.posed_spread)


def fitted_session(basis: BodyBasis, template: np.ndarray, views: list[SessionView], registered: bool) -> FittedBody:
    """The body fitted to the session's views (``template``: the rest-pose template's vertices)."""
    return fitted_views(basis, template, [view.geometry for view in views], [view.places for view in views], registered)


def calibrated_sigma(basis: BodyBasis, fitted: FittedBody, views: int) -> np.ndarray:
    """(V,) each vertex's σ (m) of a body fitted to ``views`` views, scaled as the calibration
    found for that many, and widened where the fit holds worse than the calibration fits
    (:meth:`BodyBasis.misfit`)."""
    return fitted.vertex_sigma(basis) * basis.scales(views)[0] * basis.misfit(fitted.residual_m)


def session_body(
    basis: BodyBasis,
    measurer: Measurer,
    views: list[SessionView],
    registered: bool,
    coverage: dict[str, float],
) -> SessionBody:
    """The session's body and measurements; ``coverage``: each body part's covered share."""
    fitted = fitted_session(basis, measurer.template.vertices, views, registered)
    spread_scale = basis.scales(len(views))[1] * basis.misfit(fitted.residual_m)
    vertices = fitted.vertices(basis)
    values = measurer.measure(vertices)
    drawn = [measurer.measure(body) for body in fitted.samples(basis, SAMPLES, np.random.default_rng(SEED))]
    measurements, not_measured = [], {}
    for name in MEASUREMENTS:
        value = values[name]
        if not supported(name, coverage, SEEN):
            not_measured[name] = "the session has not seen the body parts it rests on"
        elif value is None:
            not_measured[name] = "the fitted body has no torso slice there"
        else:
            spread = np.std([d[name] for d in drawn if d[name] is not None]) * spread_scale
            half = INTERVAL_Z * float(spread)
            measurements.append(Measurement(name, value, value - half, value + half))
    sigma = calibrated_sigma(basis, fitted, len(views))
    return SessionBody(vertices, sigma, measurements, not_measured, fitted)
