"""The test-time spectral fit of a decoded body: its eigenvalue gradient and what it converges to."""

import numpy as np
import pytest
import trimesh

from training.reconstruction.spectral_fit import CotangentSpectrum, fitted


@pytest.fixture(scope="module")
def ellipsoid() -> trimesh.Trimesh:
    """A closed surface without symmetric clusters: every eigenvalue simple, so each is differentiable."""
    sphere = trimesh.creation.icosphere(subdivisions=2)
    noise = np.random.default_rng(0).normal(scale=0.01, size=sphere.vertices.shape)
    return trimesh.Trimesh(sphere.vertices * [1.0, 0.8, 0.6] + noise, sphere.faces, process=False)


def test_the_sphere_s_first_nonzero_eigenvalues_are_two_over_its_radius_squared():
    sphere = trimesh.creation.icosphere(subdivisions=4, radius=0.5)
    values, functions = CotangentSpectrum(sphere.faces, 5).solve(np.asarray(sphere.vertices))
    assert abs(values[0]) < 1e-8
    np.testing.assert_allclose(values[1:4], 2 / 0.5**2, rtol=5e-3)  # l = 1, triple
    mass = sphere.area_faces.repeat(3) / 3
    lumped = np.bincount(sphere.faces.ravel(), mass, len(sphere.vertices))
    np.testing.assert_allclose(functions.T @ (lumped[:, None] * functions), np.eye(5), atol=1e-8)


def test_the_eigenvalue_gradient_matches_finite_differences(ellipsoid):
    spectrum = CotangentSpectrum(ellipsoid.faces, 8)
    vertices = np.asarray(ellipsoid.vertices)
    values, functions = spectrum.solve(vertices)
    assert np.min(np.diff(values[1:])) > 1e-3 * values[-1]  # simple: Hellmann–Feynman holds per eigenvalue
    weights = np.random.default_rng(1).normal(size=8)
    gradient = spectrum.gradient(vertices, values, functions, weights)
    direction = np.random.default_rng(2).normal(size=vertices.shape)
    step = 1e-6
    ahead, behind = (spectrum.solve(vertices + sign * step * direction)[0] @ weights for sign in (1, -1))
    np.testing.assert_allclose(np.sum(gradient * direction), (ahead - behind) / (2 * step), rtol=1e-5)


def test_a_fit_along_a_scale_component_finds_the_body_whose_spectrum_it_was(ellipsoid):
    """Eigenvalues go as 1/size²: the target is the body 1.2 times larger, the basis one component
    (the body itself, spread 0.1), so the fit must land on the coefficient 2."""
    vertices = np.asarray(ellipsoid.vertices)
    spectrum = CotangentSpectrum(ellipsoid.faces, 8)
    target = spectrum.solve(1.2 * vertices)[0]
    basis = (vertices.ravel(), 0.1 * vertices.ravel()[None])
    body = fitted(target, vertices, basis, spectrum)
    scale = np.linalg.norm(body) / np.linalg.norm(vertices)
    assert scale == pytest.approx(1.2, abs=2e-3)
