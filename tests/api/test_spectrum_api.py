"""POST /v1/spectrum through HTTP: answers, and the documented problem for every bad input."""

import json

import numpy as np
import pytest

from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from harness.builders import (
    ascii_ply,
    external_buffer,
    glb_with_external_buffer,
    mesh_bytes,
    npy_bytes,
    zip_of,
)
from tests.api.conftest import UPLOAD_CAP
from tests.conftest import disk, sphere

TRIANGLE = np.array([[0.0, 0, 0], [1, 0, 0], [0, 1, 0]])


def post(client, name: str, data: bytes, **params):
    return client.post("/v1/spectrum", params=params, files={"file": (name, data)})


def assert_problem(response, status: int, slug: str) -> dict:
    assert response.status_code == status, response.text
    assert response.headers["content-type"] == "application/problem+json"
    body = response.json()
    assert set(body) == {"type", "title", "status", "detail"}
    assert body["status"] == status
    assert body["type"] == f"/problems/{slug}"
    return body


def test_spectrum_of_a_mesh(client, patch):
    response = post(client, "patch.ply", ascii_ply(patch.vertices, patch.faces), k=12)
    assert response.status_code == 200, response.text
    body = response.json()
    expected = mesh_spectrum(patch, SpectrumOptions(k=12)).eigenvalues
    np.testing.assert_allclose(body["eigenvalues"], expected, rtol=1e-12)
    assert body["kind"] == "mesh"
    assert body["boundary"] == "dirichlet"
    assert body["components_dropped"] == 0
    assert body["vertices"] == len(patch.vertices)


def test_units_and_scale(client, patch):
    in_mm = ascii_ply(patch.vertices * 1000, patch.faces)
    metres = post(client, "p.ply", ascii_ply(patch.vertices, patch.faces)).json()["eigenvalues"]
    np.testing.assert_allclose(post(client, "p.ply", in_mm, units="mm").json()["eigenvalues"], metres, rtol=1e-8)
    np.testing.assert_allclose(post(client, "p.ply", in_mm, scale=0.001).json()["eigenvalues"], metres, rtol=1e-8)


def test_closed_point_cloud_is_close_to_the_sphere_spectrum(client):
    points = sphere(4).vertices
    body = post(client, "s.npy", npy_bytes(points), k=9, closed="true").json()
    assert body["kind"] == "points" and body["boundary"] == "none"
    np.testing.assert_allclose(body["eigenvalues"][1:], [2, 2, 2, 6, 6, 6, 6, 6], rtol=0.05)


def test_partial_point_cloud_needs_its_boundary(client):
    mesh = disk(rings=25)
    points = mesh.vertices
    assert_problem(post(client, "d.npy", npy_bytes(points), k=5), 422, "missing-boundary")
    rim = np.flatnonzero(np.linalg.norm(points[:, :2], axis=1) > 1 - 1e-9)
    flagged = client.post(
        "/v1/spectrum",
        params={"k": 3},
        files={"file": ("d.npy", npy_bytes(points))},
        data={"boundary": json.dumps(rim.tolist())},
    )
    assert flagged.status_code == 200, flagged.text
    np.testing.assert_allclose(flagged.json()["eigenvalues"], [5.7832, 14.682, 14.682], rtol=0.05)
    in_ply = post(client, "d.ply", ascii_ply(points, boundary=np.isin(np.arange(len(points)), rim)), k=3)
    np.testing.assert_allclose(in_ply.json()["eigenvalues"], flagged.json()["eigenvalues"])


@pytest.mark.parametrize(
    ("name", "data", "slug"),
    [
        ("broken.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\nnot numbers", "unreadable-file"),
        ("garbage.obj", bytes(range(256)) * 4, "unreadable-file"),
        (
            "nan.ply",
            ascii_ply(np.array([[0, 0, np.nan], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]])),
            "invalid-geometry",
        ),
        (
            "inf.ply",
            ascii_ply(np.array([[0, 0, np.inf], [1, 0, 0], [0, 1, 0]]), np.array([[0, 1, 2]])),
            "invalid-geometry",
        ),
        ("out_of_range.ply", ascii_ply(TRIANGLE, np.array([[0, 1, 7]])), "invalid-geometry"),
        ("negative.ply", ascii_ply(TRIANGLE, np.array([[0, 1, -2]])), "invalid-geometry"),
        ("one_triangle.ply", ascii_ply(TRIANGLE, np.array([[0, 1, 2]])), "invalid-geometry"),
        (
            "flat.ply",
            ascii_ply(np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0], [3, 0, 0]]), np.array([[0, 1, 2], [1, 2, 3]])),
            "invalid-geometry",
        ),
    ],
)
def test_bad_files_get_a_422_problem(client, name, data, slug):
    assert_problem(post(client, name, data), 422, slug)


def test_obj_material_library_pointing_at_a_server_file_is_never_read(client, patch):
    plain = mesh_bytes(patch, "obj")
    hostile = post(client, "scan.obj", b"mtllib /etc/passwd\n" + plain)
    assert hostile.status_code == 200
    assert hostile.json()["eigenvalues"] == post(client, "scan.obj", plain).json()["eigenvalues"]


def test_glb_buffer_uri_pointing_at_a_server_file_is_refused(client, patch, tmp_path):
    target = tmp_path / "buffer.bin"
    target.write_bytes(external_buffer(patch))
    response = post(client, "scan.glb", glb_with_external_buffer(str(target), patch))
    assert_problem(response, 422, "external-reference")


@pytest.mark.parametrize("name", ["scan.zip", "scan.tar", "scan.exe"])
def test_archives_and_unknown_types_get_415(client, patch, name):
    data = zip_of("scan.ply", ascii_ply(patch.vertices, patch.faces))
    assert_problem(post(client, name, data), 415, "unsupported-file-type")


def test_zip_sent_under_an_allowed_name_does_not_parse(client, patch):
    data = zip_of("scan.ply", ascii_ply(patch.vertices, patch.faces))
    assert_problem(post(client, "scan.ply", data), 422, "unreadable-file")


def test_chunked_upload_over_the_cap_gets_413(client):
    boundary = "cap-test"
    head = (f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="big.ply"\r\n\r\n').encode()

    def body():
        yield head
        for _ in range(UPLOAD_CAP // 65536 + 2):
            yield b"0" * 65536

    response = client.post(
        "/v1/spectrum",
        content=body(),
        headers={"content-type": f"multipart/form-data; boundary={boundary}"},
    )
    assert "content-length" not in response.request.headers
    assert_problem(response, 413, "upload-too-large")


def test_declared_length_over_the_cap_gets_413(client):
    response = post(client, "big.ply", b"x" * (UPLOAD_CAP + 1))
    assert_problem(response, 413, "upload-too-large")


@pytest.mark.parametrize("k", [0, 201, "many"])
def test_k_out_of_range_gets_422(client, patch, k):
    body = assert_problem(post(client, "p.ply", ascii_ply(patch.vertices, patch.faces), k=k), 422, "invalid-request")
    assert "k" in body["detail"]


def test_too_many_vertices_gets_422(client):
    mesh = disk(rings=130)  # ~51 k vertices, over the test cap of 50 k
    assert_problem(post(client, "d.ply", mesh_bytes(mesh, "ply")), 422, "too-many-vertices")


def test_health_and_readiness(client):
    assert client.get("/healthz").json() == {"status": "ok"}
    assert client.get("/readyz").json() == {"status": "ready"}


def test_openapi_documents_the_problem_responses(client):
    responses = client.get("/openapi.json").json()["paths"]["/v1/spectrum"]["post"]["responses"]
    assert {"200", "413", "415", "422"} <= set(responses)
