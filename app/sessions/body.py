"""A session's body: the rest-pose body fitted to its views' points and places, and its measurements.

The views must stand in one frame and one pose: registered views as they came, views in their
own frames once aligned (:func:`app.sessions.aligned.aligned_views`). A spread of the views'
points, drawn by area so that the fine mesh of a face or a hand does not outweigh the back, is
fitted (:func:`app.inference.bodyfit.fit_body`); the measurements are taken on the fitted body,
each with an interval from bodies drawn from the fit's posterior (scaled as the calibration on
anny sessions found), and only where the session saw the parts a measurement rests on.
"""

from dataclasses import dataclass

import numpy as np

from app.contract import INTERVAL_Z
from app.inference.bodyfit import BodyBasis, FittedBody, fit_body
from app.inference.measurements import MEASUREMENTS, Measurer, supported
from app.sessions.aligned import aligned_views
from app.sessions.session import SessionView

FIT_POINTS = 4000  # the points a fit reads: its cost, about 3 s on one core
SAMPLES = 16  # posterior bodies an interval is read from
SEEN = 0.3  # a body part whose covered share is below this was not seen enough to measure on
SEED = 0  # the draws are fixed: one session, one answer


class NotInOneFrame(ValueError):
    """Views in their own frames that could not be brought together."""


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


def fitted_points(views: list[SessionView], registered: bool) -> tuple[np.ndarray, np.ndarray]:
    """(n, 3) points in one frame and their (n, 3) places, up to FIT_POINTS drawn by area."""
    geometry = [view.geometry for view in views]
    if not registered and len(views) > 1:
        moved = aligned_views(geometry, [view.places for view in views])
        if moved is None:
            raise NotInOneFrame("the views could not be brought into one frame through their places")
        geometry = moved
    points = np.concatenate([g.points for g in geometry])
    places = np.concatenate([view.places for view in views])
    mass = np.concatenate([g.mass for g in geometry])
    if len(points) > FIT_POINTS:
        chosen = np.random.default_rng(SEED).choice(len(points), FIT_POINTS, replace=False, p=mass / mass.sum())
        points, places = points[chosen], places[chosen]
    return points, places


def session_body(
    basis: BodyBasis,
    measurer: Measurer,
    views: list[SessionView],
    registered: bool,
    coverage: dict[str, float],
) -> SessionBody:
    """The session's body and measurements; ``coverage``: each body part's covered share."""
    points, places = fitted_points(views, registered)
    fitted = fit_body(basis, points, places, measurer.template.vertices)
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
            spread = np.std([d[name] for d in drawn if d[name] is not None]) * basis.spread_scale
            half = INTERVAL_Z * float(spread)
            measurements.append(Measurement(name, value, value - half, value + half))
    return SessionBody(vertices, fitted.vertex_sigma(basis) * basis.sigma_scale, measurements, not_measured, fitted)
