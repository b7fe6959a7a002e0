"""The body fit against bodies whose shape and pose are known: drawn from the served basis, posed
by its own skinning, seen whole or in part."""

from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.contract import BODY_FILE
from app.inference.bodyfit import BodyBasis, NotEnoughSeen, fit_body
from app.inference.template import PART_NAMES, Template
from app.sessions.body import calibrated_sigma, fitted_views
from app.sessions.fused import View

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def basis() -> BodyBasis:
    return BodyBasis.load(MODELS / BODY_FILE)


@pytest.fixture(scope="module")
def template() -> Template:
    return Template.load(MODELS)


def posed(basis: BodyBasis, rest: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """``rest`` posed by the basis's skinning: each limb part turned up to 25°, the whole body
    turned and moved as a scanner's frame would have it."""
    parts = basis.weights.shape[1]
    angles = np.zeros((parts, 3))
    limbs = [i for i, name in enumerate(PART_NAMES) if name.split("_")[-1] in ("arm", "forearm", "thigh", "shin")]
    angles[limbs] = rng.uniform(-np.radians(25), np.radians(25), size=(len(limbs), 3))
    rotations = Rotation.from_rotvec(angles).as_matrix()
    pivots = np.array(
        [
            rest[basis.weights[:, b] > 0.5].mean(axis=0) if (basis.weights[:, b] > 0.5).any() else np.zeros(3)
            for b in range(parts)
        ]
    )
    translations = pivots - np.einsum("bij,bj->bi", rotations, pivots)
    moved = np.einsum("bij,vj->vbi", rotations, rest) + translations[None]
    body = np.einsum("vb,vbi->vi", basis.weights, moved)
    frame = Rotation.from_rotvec(rng.normal(size=3)).as_matrix()
    return body @ frame.T + rng.normal(size=3)


def test_a_posed_body_seen_whole_comes_back_at_rest(basis, template):
    rng = np.random.default_rng(0)
    truth = basis.rest(rng.normal(scale=0.8, size=len(basis.components)))
    seen = rng.choice(len(truth), 3000, replace=False)
    body = posed(basis, truth, rng)
    fitted = fit_body(basis, body[seen], template.vertices[seen], template.vertices)
    error = np.linalg.norm(fitted.vertices(basis) - truth, axis=1)
    assert error.mean() < 0.002  # far below the 20–90 mm that separate one person from another
    assert fitted.residual_m < 0.002
    assert np.linalg.norm(fitted.posed[0] - body, axis=1).mean() < 0.002  # and as it stood, in its frame


def test_a_body_seen_in_part_is_less_certain_than_seen_whole(basis, template):
    rng = np.random.default_rng(1)
    truth = basis.rest(rng.normal(scale=0.8, size=len(basis.components)))
    body = posed(basis, truth, rng)
    front = np.flatnonzero(template.vertices[:, 1] < np.median(template.vertices[:, 1]))  # −y is the body's front
    whole = rng.choice(len(truth), 4000, replace=False)
    half = rng.choice(front, 2000, replace=False)
    fits = [fit_body(basis, body[seen], template.vertices[seen], template.vertices) for seen in (whole, half)]
    sigma_whole, sigma_half = (fit.vertex_sigma(basis) for fit in fits)
    assert np.median(sigma_half / sigma_whole) > 1.2
    assert np.linalg.norm(fits[1].vertices(basis) - truth, axis=1)[front].mean() < 0.015  # people differ by 20–90 mm


def test_too_few_points_are_refused(basis, template):
    with pytest.raises(NotEnoughSeen):
        fit_body(basis, template.vertices[:50], template.vertices[:50], template.vertices)


def test_one_body_seen_in_two_poses_comes_back_once(basis, template):
    rng = np.random.default_rng(2)
    truth = basis.rest(rng.normal(scale=0.8, size=len(basis.components)))
    first, second = posed(basis, truth, rng), posed(basis, truth, rng)  # two poses, two frames
    front = template.vertices[:, 1] < np.median(template.vertices[:, 1])
    seen = [
        rng.choice(np.flatnonzero(front), 2000, replace=False),
        rng.choice(np.flatnonzero(~front), 2000, replace=False),
    ]
    points = np.concatenate([first[seen[0]], second[seen[1]]])
    places = template.vertices[np.concatenate(seen)]
    poses = np.repeat([0, 1], 2000)
    apart = fit_body(basis, points, places, template.vertices, poses)
    error = np.linalg.norm(apart.vertices(basis) - truth, axis=1).mean()
    assert error < 0.005
    as_one = fit_body(basis, points, places, template.vertices)  # read as one pose, the two halves disagree
    assert np.linalg.norm(as_one.vertices(basis) - truth, axis=1).mean() > 2 * error


def test_a_fit_is_less_certain_in_proportion_as_it_holds_worse_than_the_calibration_fits(basis, template):
    """A session's body keeps its calibrated σ where the fit leaves its points no farther from
    the body than the calibration fits' median gap, and widens it by the ratio beyond; so does
    the shape distance past which the person scanned is taken for one not stored."""
    rng = np.random.default_rng(3)
    body = posed(basis, basis.rest(rng.normal(scale=0.8, size=len(basis.components))), rng)
    seen = rng.choice(len(body), 3000, replace=False)
    view = View(body[seen], np.ones(len(seen)), np.zeros(len(seen), bool), np.empty((0, 2), np.int64))
    plain = fit_body(basis, body[seen], template.vertices[seen], template.vertices)
    for reference, widened in ((plain.residual_m * 2, 1.0), (plain.residual_m / 3, 3.0)):
        calibrated = replace(basis, fit_residual_m=reference)
        assert calibrated.misfit(plain.residual_m) == pytest.approx(widened)
        fitted = fitted_views(calibrated, template.vertices, [view], [template.vertices[seen]], registered=True)
        expected = plain.vertex_sigma(basis) * basis.scales(1)[0] * widened
        np.testing.assert_allclose(calibrated_sigma(calibrated, fitted, 1), expected, rtol=1e-9)
        assert calibrated.unknown_for(fitted.residual_m) == pytest.approx(basis.unknown_distance * widened)
