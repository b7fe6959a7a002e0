"""Unit slips are answered, with a warning that names the likely unit: a shape no human scan
is as large or as small, and operands of one request far apart in size."""

import json

import numpy as np

from app.geometry.plausibility import MAX_SIZE_RATIO, PLAUSIBLE_AREA_M2, size_warnings
from harness.builders import mesh_bytes
from tests.api.test_spectrum_api import post
from tests.conftest import bumpy_patch


def _patch_in_mm() -> bytes:
    patch = bumpy_patch(seed=1, n=300)
    return mesh_bytes(type(patch)(patch.vertices * 1000, patch.faces), "ply")


def test_a_shape_in_millimetres_sent_as_metres_is_answered_with_a_warning_naming_mm(client):
    slipped = post(client, "scan.ply", _patch_in_mm()).json()
    right = post(client, "scan.ply", _patch_in_mm(), units="mm").json()
    assert not PLAUSIBLE_AREA_M2[0] <= slipped["area_m2"] <= PLAUSIBLE_AREA_M2[1]
    assert len(slipped["warnings"]) == 1 and "(units=mm)" in slipped["warnings"][0]
    assert right["warnings"] == []
    np.testing.assert_allclose(np.asarray(slipped["eigenvalues"]) * 1e6, right["eigenvalues"], rtol=1e-6)


def test_operands_far_apart_in_size_are_united_with_a_warning(client):
    right = post(client, "scan.ply", _patch_in_mm(), units="mm").json()["eigenvalues"]
    shrunk = (np.asarray(right) * 1e6).tolist()  # the same patch, 1000× smaller
    body = client.post("/v1/union", data={"spectra": json.dumps([right, shrunk])}).json()
    assert len(body["warnings"]) == 1
    assert "spectra[0] is 1000× the size of spectra[1]" in body["warnings"][0]
    near = (np.asarray(right) / (0.9 * MAX_SIZE_RATIO) ** 2).tolist()  # 9× larger: within the bound
    assert client.post("/v1/union", data={"spectra": json.dumps([right, near])}).json()["warnings"] == []


def test_a_file_operands_warning_is_carried_into_the_union_and_retrieval(client):
    right = post(client, "scan.ply", _patch_in_mm(), units="mm").json()["eigenvalues"]
    form = {"spectra": json.dumps([right])}
    files = {"files": ("slip.ply", _patch_in_mm())}
    for route in ("/v1/union", "/v1/retrieve", "/v1/localize"):
        warnings = client.post(route, data=form, files=files).json()["warnings"]
        assert any(w.startswith("files[0] slip.ply: the shape's area") for w in warnings), (route, warnings)
        assert any("1000× the size of" in w for w in warnings), (route, warnings)


def test_the_size_warning_names_the_operands_it_compares():
    """An operand without a positive eigenvalue takes no part, and does not shift the names:
    [zeros, A, A of a body 100× smaller] names spectra[2] against spectra[1]."""
    spectrum = np.linspace(1.0, 20.0, 20)
    sources = ["spectra[0]", "spectra[1]", "spectra[2]"]
    (warning,) = size_warnings([np.zeros(20), spectrum, 1e4 * spectrum], sources)
    assert warning.startswith("spectra[1] is 100× the size of spectra[2]")
