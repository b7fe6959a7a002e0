"""Property-based: any vertex/face arrays, and any damaged or arbitrary file, give a finite spectrum
or our validation error, never a crash."""

import numpy as np
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from app.geometry.errors import GeometryError
from app.geometry.pipeline import SpectrumOptions, cloud_spectrum, mesh_spectrum, spectrum_from_bytes
from app.geometry.shapes import Mesh, PointCloud
from harness.builders import mesh_bytes, npy_bytes
from tests.conftest import bumpy_patch

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


def _valid_files() -> dict[str, bytes]:
    """A small bumpy patch in every text and binary format the service reads."""
    patch = bumpy_patch(seed=7, n=120)
    files = {kind: mesh_bytes(patch, kind) for kind in ("ply", "obj", "off", "stl", "glb")}
    files["xyz"] = "\n".join(" ".join(map(str, p)) for p in patch.vertices).encode()
    files["npy"] = npy_bytes(patch.vertices)
    return files


VALID_FILES = _valid_files()


@st.composite
def damaged_files(draw):
    """A valid file with random bytes overwritten, a tail cut off, or bytes spliced in."""
    kind = draw(st.sampled_from(sorted(VALID_FILES)))
    data = bytearray(VALID_FILES[kind])
    for _ in range(draw(st.integers(1, 8))):
        at = draw(st.integers(0, len(data) - 1))
        data[at] = draw(st.integers(0, 255))
    if draw(st.booleans()):
        data = data[: draw(st.integers(0, len(data)))]
    if draw(st.booleans()):
        at = draw(st.integers(0, len(data)))
        data[at:at] = draw(st.binary(max_size=64))
    return kind, bytes(data)


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(damaged_files())
def test_any_damaged_file_gives_a_finite_spectrum_or_a_geometry_error(case):
    kind, data = case
    try:
        values = spectrum_from_bytes(data, kind, SpectrumOptions(k=3, closed=kind in ("xyz", "npy"))).eigenvalues
    except GeometryError:
        return
    assert len(values) == 3 and np.all(np.isfinite(values))


@settings(max_examples=200, deadline=None)
@given(st.sampled_from(sorted(VALID_FILES)), st.binary(max_size=512))
def test_any_bytes_give_a_finite_spectrum_or_a_geometry_error(kind, data):
    try:
        values = spectrum_from_bytes(data, kind, SpectrumOptions(k=2, closed=True)).eigenvalues
    except GeometryError:
        return
    assert np.all(np.isfinite(values))
