"""Property-based: any vertex/face arrays give a finite spectrum or our validation error, never a crash."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from app.geometry.errors import GeometryError
from app.geometry.pipeline import SpectrumOptions, cloud_spectrum, mesh_spectrum
from app.geometry.shapes import Mesh, PointCloud

coordinates = st.one_of(st.floats(-2.0, 2.0), st.sampled_from([np.nan, np.inf, -np.inf, 1e308, -1e308, 0.0, 1e-300]))


@st.composite
def meshes(draw):
    n = draw(st.integers(1, 40))
    vertices = draw(arrays(np.float64, (n, 3), elements=coordinates))
    m = draw(st.integers(1, 60))
    faces = draw(arrays(np.int64, (m, 3), elements=st.integers(-3, n + 2)))
    return Mesh(vertices, faces)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(meshes(), st.integers(1, 4))
def test_any_mesh_gives_a_finite_spectrum_or_a_geometry_error(mesh, k):
    try:
        values = mesh_spectrum(mesh, SpectrumOptions(k=k)).eigenvalues
    except GeometryError:
        return
    assert len(values) == k and np.all(np.isfinite(values)) and np.all(np.diff(values) >= -1e-9)


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(arrays(np.float64, st.tuples(st.integers(1, 60), st.just(3)), elements=coordinates), st.booleans())
def test_any_point_cloud_gives_a_finite_spectrum_or_a_geometry_error(points, closed):
    boundary = np.arange(len(points)) % 5 == 0
    try:
        values = cloud_spectrum(PointCloud(points, boundary), SpectrumOptions(k=2, closed=closed)).eigenvalues
    except GeometryError:
        return
    assert np.all(np.isfinite(values))
