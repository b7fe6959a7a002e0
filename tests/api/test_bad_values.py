"""Values that parsed but were wrong: each is a 422 with its problem type, or a documented
repair whose answer is checked against the shape without the defect — never a 500, never a
200 carrying null or a silently different request.
"""

import io
import json

import numpy as np
import pytest
import trimesh

from harness.builders import ascii_ply, mesh_bytes, npy_bytes
from tests.api.conftest import API_KEY
from tests.api.test_spectrum_api import assert_problem, post
from tests.conftest import bumpy_patch, sphere

K = 20


def _union(client, spectra_text: str, route: str = "/v1/union"):
    return client.post(route, data={"spectra": spectra_text})


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("[[" + "[" * 5000 + "]" * 5000 + "]]", "nests too deeply"),  # RecursionError
        ("[[" + "1" * 5000 + "]]", "not valid JSON"),  # past Python's int-digits limit
        ("[[" + "9" * 400 + "]]", "too large for a float"),  # OverflowError in float()
        ('[["1"' + ", 2" * (K - 1) + "]]", "list of numbers"),  # numpy read "1" as 1.0
        ("[[true" + ", 2" * (K - 1) + "]]", "list of numbers"),  # and true as 1.0
    ],
)
def test_malformed_spectra_json_is_a_422(client, text, says):
    body = assert_problem(_union(client, text), 422, "invalid-spectrum")
    assert says in body["detail"]


@pytest.mark.parametrize("route", ["/v1/union", "/v1/localize", "/v1/retrieve"])
def test_spectra_past_what_the_models_represent_are_a_422_not_nulls(client, route):
    """[[1e39]*20]*2 passed the finite check, overflowed float32 and came back as null."""
    body = assert_problem(_union(client, json.dumps([[1e39] * K] * 2), route), 422, "invalid-spectrum")
    assert "above 1e+15" in body["detail"]


@pytest.mark.parametrize(
    ("text", "says"),
    [
        ("[99999999999999999999]", "indices in [0,"),  # OverflowError inside the solver worker
        ("[" * 5000 + "]" * 5000, "nests too deeply"),
        ("[1.5]", "integers"),
    ],
)
def test_malformed_boundary_indices_are_a_422(client, text, says):
    cloud = sphere(subdivisions=3).vertices
    response = client.post("/v1/spectrum", files={"file": ("c.xyz", _xyz(cloud))}, data={"boundary": text})
    assert says in assert_problem(response, 422, "invalid-geometry")["detail"]


def _xyz(points: np.ndarray) -> bytes:
    return "".join(f"{x} {y} {z}\n" for x, y, z in points).encode()


def test_a_repeated_query_parameter_is_a_422_not_the_last_one(client):
    """k=500&k=5 was solved for k = 5."""
    patch = bumpy_patch(seed=1, n=300)
    response = client.post("/v1/spectrum?k=500&k=5", files={"file": ("p.ply", mesh_bytes(patch, "ply"))})
    assert "k given more than once" in assert_problem(response, 422, "invalid-request")["detail"]
    assert_problem(client.get("/v1/shapes?limit=1&limit=2"), 422, "invalid-request")


def test_a_repeated_form_field_is_a_422_and_repeated_files_are_operands(client):
    spectrum = json.dumps([list(range(1, K + 1))])
    response = client.post("/v1/union", data={"spectra": [spectrum, spectrum]})
    assert "spectra given more than once" in assert_problem(response, 422, "invalid-request")["detail"]
    patch = mesh_bytes(bumpy_patch(seed=1, n=300), "ply")
    response = client.post("/v1/union", files=[("files", ("a.ply", patch)), ("files", ("b.ply", patch))])
    assert response.status_code == 200, response.text
    assert len(response.json()["operands"]) == 2


def test_a_repeated_form_field_is_a_422_whatever_the_media_type_s_case(client):
    """Starlette reads 'Multipart/Form-Data' as a form; so does the check for repeats."""
    body = b'--b\r\nContent-Disposition: form-data; name="spectra"\r\n\r\n[[1, 2]]\r\n' * 2 + b"--b--\r\n"
    headers = {"content-type": "Multipart/Form-Data; boundary=b"}
    response = client.post("/v1/union", content=body, headers=headers)
    assert "spectra given more than once" in assert_problem(response, 422, "invalid-request")["detail"]


def test_a_shape_scaled_to_nothing_is_a_422_not_a_spectrum_of_1e60(client):
    patch = mesh_bytes(bumpy_patch(seed=1, n=300), "ply")
    response = post(client, "tiny.ply", patch, scale=1e-30)
    assert "are its units right" in assert_problem(response, 422, "invalid-geometry")["detail"]


def test_an_npz_archive_named_npy_is_a_422(client):
    archive = io.BytesIO()
    np.savez(archive, points=sphere(subdivisions=3).vertices)
    assert ".npz archive" in assert_problem(post(client, "c.npy", archive.getvalue()), 422, "unreadable-file")["detail"]


def test_a_complex_npy_is_a_422_not_its_real_part(client):
    points = sphere(subdivisions=3).vertices * (1 + 1j)
    assert "real-valued" in assert_problem(post(client, "c.npy", npy_bytes(points)), 422, "unreadable-file")["detail"]


def test_a_far_outlier_is_dropped_from_a_point_cloud_and_the_spectrum_is_the_clouds(client):
    """One point 100 m away gave a partial cloud a negative λ₁; it is a cluster of its own now."""
    points = sphere(subdivisions=4).vertices
    points = points[points[:, 2] > 0]
    flags = points[:, 2] < 0.08
    clean = client.post("/v1/spectrum", files={"file": ("c.ply", ascii_ply(points, boundary=flags))})
    noisy_points, noisy_flags = np.r_[points, [[0, 0, 100.0]]], np.r_[flags, False]
    noisy = client.post("/v1/spectrum", files={"file": ("c.ply", ascii_ply(noisy_points, boundary=noisy_flags))})
    assert clean.status_code == noisy.status_code == 200, noisy.text
    assert noisy.json()["components_dropped"] == 1 and clean.json()["components_dropped"] == 0
    np.testing.assert_allclose(noisy.json()["eigenvalues"], clean.json()["eigenvalues"], rtol=1e-9)
    assert min(noisy.json()["eigenvalues"]) > 0


def test_a_partial_surface_is_not_stored_as_a_complete_shape(client):
    """The store is of complete shapes; a Dirichlet spectrum filed there would match no union."""
    patch = bumpy_patch(seed=1, n=300)
    response = client.post(
        "/v1/shapes",
        data={"label": "half"},
        files={"file": ("half.ply", mesh_bytes(patch, "ply"))},
        headers={"X-API-Key": API_KEY},
    )
    assert "has a boundary" in assert_problem(response, 422, "invalid-geometry")["detail"]
    closed = trimesh.creation.icosphere(subdivisions=3)
    response = client.post(
        "/v1/shapes",
        data={"label": "ball"},
        files={"file": ("ball.ply", closed.export(file_type="ply"))},
        headers={"X-API-Key": API_KEY},
    )
    assert response.status_code == 201, response.text


def test_an_upload_under_another_field_name_is_told_what_it_sent(client):
    """``-F files=@a.ply`` on /v1/spectrum answered only "body.file: Field required"."""
    patch = mesh_bytes(bumpy_patch(seed=1, n=300), "ply")
    response = client.post("/v1/spectrum", files={"files": ("a.ply", patch)})
    detail = assert_problem(response, 422, "invalid-request")["detail"]
    assert "body.file" in detail and "it sent 'files'" in detail
    assert "it sent" not in assert_problem(client.post("/v1/spectrum"), 422, "invalid-request")["detail"]


def test_a_request_without_operands_names_the_field_it_should_have_used(client):
    """``-F file=@a.ply`` on /v1/union sent no operand and was answered invalid-spectrum "got 0"."""
    patch = mesh_bytes(bumpy_patch(seed=1, n=300), "ply")
    response = client.post("/v1/union", files={"file": ("a.ply", patch)})
    detail = assert_problem(response, 422, "invalid-request")["detail"]
    assert "'files'" in detail and "it sent 'file'" in detail
    assert_problem(client.post("/v1/localize"), 422, "invalid-request")
    many = json.dumps([list(range(1, K + 1))] * 33)
    assert "at most 32 operands" in assert_problem(_union(client, many), 422, "invalid-request")["detail"]
