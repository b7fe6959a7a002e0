"""``POST /v1/correspondence`` and the regions and overlaps the union routes read from it.

The truths: a part cut from the template is its own correspondence (each of its vertices *is* a
template vertex); an upload's frame, units and winding change nothing the network reads; the
region of a union is the union of its parts' regions; a service whose models have no
correspondence graph answers as before (501 here, the spectral localizer there).
"""

import io
import json

import numpy as np
import pytest
import trimesh
from fastapi.testclient import TestClient
from scipy.spatial.transform import Rotation

from app.contract import CORRESPONDENCE_FILE
from app.inference.template import PART_NAMES
from app.main import create_app
from app.samples import PARTS
from harness.builders import ascii_ply
from tests.api.conftest import correspond, settings_for, settings_without
from tests.api.test_spectrum_api import assert_problem

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def test_a_template_part_is_placed_on_itself(client, samples, template):
    """Each vertex of a part cut from the template lands near itself, and the region it covers
    leaves out the body parts it lacks."""
    name = "no_head_neck.ply"
    answer = correspond(client, name, samples[name])
    assert answer.status_code == 200, answer.text
    body = answer.json()
    mesh = trimesh.load(io.BytesIO(samples[name]), file_type="ply", process=False)
    position = np.array(body["position"])
    truth = np.asarray(mesh.vertices)[np.array(body["vertex_indices"])]
    assert len(position) == body["vertices"] == len(body["confidence"]) == len(body["template_vertex"])
    assert np.median(np.linalg.norm(position - truth, axis=1)) < 0.10
    assert all(0.0 <= c <= 1.0 for c in body["confidence"])
    coverage = body["region"]["part_coverage"]
    assert set(coverage) == set(PART_NAMES)
    assert coverage["head"] < 0.3 and coverage["hips"] > 0.7 and coverage["torso"] > 0.7


def test_relaxed_places_lie_closer_to_the_truth_and_say_so(client, samples):
    """Asked for relaxed places, the answer says so (JSON and .npz), every vertex still answered,
    and they lie closer to the truth (a template part's vertices are their own places) than the
    network's: 2.0 → 1.4 cm on average on the README's part."""
    name = "no_left_forearm_hand.ply"
    mesh = trimesh.load(io.BytesIO(samples[name]), file_type="ply", process=False)
    network = correspond(client, name, samples[name]).json()
    relaxed = correspond(client, name, samples[name], places="relaxed").json()
    assert (network["places"], relaxed["places"]) == ("network", "relaxed")
    assert relaxed["vertex_indices"] == network["vertex_indices"]
    truth = np.asarray(mesh.vertices)[np.array(relaxed["vertex_indices"])]
    network_error, relaxed_error = (
        np.linalg.norm(np.array(body["position"]) - truth, axis=1).mean() for body in (network, relaxed)
    )
    assert relaxed_error < 0.8 * network_error
    arrays = np.load(io.BytesIO(correspond(client, name, samples[name], places="relaxed", format="npz").content))
    assert str(arrays["places"]) == "relaxed"
    np.testing.assert_allclose(arrays["position"], relaxed["position"], atol=1e-4)


def test_a_service_with_a_smaller_budget_answers_every_vertex_through_a_coarser_copy(tmp_path, samples):
    """``placed_vertices`` set to 2 000: the 9 k-vertex part is read through a copy of ~2 000
    vertices (so its vertices share ~2 000 places), and still every uploaded vertex gets its
    place, near itself (the template part's vertices are their own places)."""
    name = "no_head_neck.ply"
    settings = settings_for(tmp_path / "shapes.sqlite").model_copy(update={"placed_vertices": 2_000})
    with TestClient(create_app(settings)) as coarse:
        body = correspond(coarse, name, samples[name]).json()
    mesh = trimesh.load(io.BytesIO(samples[name]), file_type="ply", process=False)
    truth = np.asarray(mesh.vertices)[np.array(body["vertex_indices"])]
    assert body["vertices"] == len(body["position"]) == len(mesh.vertices)
    assert body["placed_on"] <= 2_100
    assert len(np.unique(np.array(body["position"]), axis=0)) <= body["placed_on"]
    assert np.median(np.linalg.norm(np.array(body["position"]) - truth, axis=1)) < 0.10


def test_frame_units_and_winding_do_not_move_the_places(client, samples):
    """The part turned, moved, written in centimetres with its faces turned inward is placed
    where it was: the network reads only intrinsic, outward-oriented inputs."""
    name = "no_left_forearm_hand.ply"
    mesh = trimesh.load(io.BytesIO(samples[name]), file_type="ply", process=False)
    turn = Rotation.from_euler("xyz", [0.3, 2.0, -1.2]).as_matrix()
    moved = (np.asarray(mesh.vertices) @ turn.T + [0.4, -1.0, 2.0]) * 100.0
    upload = ascii_ply(moved, np.asarray(mesh.faces)[:, ::-1])
    before = correspond(client, name, samples[name]).json()
    after = correspond(client, "moved.ply", upload, units="cm").json()
    assert after["vertex_indices"] == before["vertex_indices"]
    np.testing.assert_allclose(after["position"], before["position"], atol=2e-3)
    assert after["region"]["vertices"] == before["region"]["vertices"]


def test_npz_and_ply_carry_what_the_json_says(client, samples):
    name = "no_head_neck.ply"
    body = correspond(client, name, samples[name]).json()
    arrays = np.load(io.BytesIO(correspond(client, name, samples[name], format="npz").content), allow_pickle=False)
    np.testing.assert_allclose(arrays["position"], body["position"], atol=1e-4)
    np.testing.assert_array_equal(arrays["template_vertex"], body["template_vertex"])
    np.testing.assert_array_equal(arrays["region"], body["region"]["vertices"])
    assert int(arrays["placed_on"]) == body["placed_on"] < body["vertices"]  # 9 045 vertices, read through a copy
    ply = correspond(client, name, samples[name], format="ply")
    assert ply.headers["content-type"] == "application/ply"
    coloured = trimesh.load(io.BytesIO(ply.content), file_type="ply", process=False)
    assert len(coloured.vertices) == body["vertices"]


def test_localize_of_uploads_is_the_union_of_their_regions(client, samples):
    files = [("files", (name, data)) for name, data in samples.items()]
    answer = client.post("/v1/localize", files=files)
    assert answer.status_code == 200, answer.text
    body = answer.json()
    assert body["located_by"] == "correspondence"
    assert len(body["vertex_confidence"]) == len(body["vertices"])
    each = [set(correspond(client, name, data).json()["region"]["vertices"]) for name, data in samples.items()]
    assert set(body["vertices"]) == each[0] | each[1]
    spectra = json.dumps([operand["eigenvalues"] for operand in body["operands"]])
    by_spectrum = client.post("/v1/localize", data={"spectra": spectra}).json()
    assert by_spectrum["located_by"] == "spectrum" and by_spectrum["vertex_confidence"] is None


def test_union_of_uploads_measures_its_overlap_and_a_told_one_wins(chain_client, samples):
    files = [("files", (name, data)) for name, data in samples.items()]
    measured = chain_client.post("/v1/union", files=files).json()
    assert measured["overlaps_from"] == "correspondence"
    assert len(measured["overlaps"]) == 1 and 0.0 <= measured["overlaps"][0] <= 1.0
    assert len(measured["overlaps_told"]) == 1
    told = chain_client.post("/v1/union", files=files, params={"overlap": "0.25"}).json()
    assert told["overlaps_from"] == "told" and told["overlaps"] == [0.25] and told["overlaps_told"] == [True]
    spectra = json.dumps([operand["eigenvalues"] for operand in measured["operands"]])
    untold = chain_client.post("/v1/union", data={"spectra": spectra}).json()
    assert untold["overlaps_from"] is None and untold["overlaps"] == []


@pytest.mark.parametrize(
    ("data", "status"),
    [
        (b"", 422),
        (b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nend_header\n", 422),
        (ascii_ply(np.array([[0, 0, 0], [1, 0, 0], [np.nan, 1, 0]]), np.array([[0, 1, 2]])), 422),
    ],
)
def test_bad_uploads_get_a_problem(client, data, status):
    answer = correspond(client, "bad.ply", data)
    assert answer.status_code == status
    assert answer.headers["content-type"] == "application/problem+json"


def test_without_the_graph_the_service_answers_as_before(tmp_path, samples):
    settings = settings_without(tmp_path, CORRESPONDENCE_FILE)
    with TestClient(create_app(settings)) as client:
        name = "no_head_neck.ply"
        missing = correspond(client, name, samples[name])
        assert missing.status_code == 501
        assert missing.json()["type"] == "/problems/correspondence-unavailable"
        files = [("files", (n, d)) for n, d in samples.items()]
        assert client.post("/v1/localize", files=files).json()["located_by"] == "spectrum"
        assert client.post("/v1/union", files=files).json()["overlaps_from"] is None


def test_spectra_sent_with_their_regions_are_placed_as_their_uploads(chain_client, samples):
    """A session's parts sent back as spectra with the region tokens /v1/correspondence gave are
    localized and united exactly as the uploads are."""
    placed = [correspond(chain_client, name, data).json() for name, data in samples.items()]
    form = {
        "spectra": json.dumps([part["eigenvalues"] for part in placed]),
        "regions": json.dumps([part["region"]["token"] for part in placed]),
    }
    files = [("files", (name, data)) for name, data in samples.items()]
    by_files = chain_client.post("/v1/localize", files=files).json()
    by_spectra = chain_client.post("/v1/localize", data=form).json()
    assert by_spectra["located_by"] == "correspondence" and by_spectra["vertices"] == by_files["vertices"]
    assert by_spectra["overlaps"] == pytest.approx(by_files["overlaps"])
    np.testing.assert_allclose(by_spectra["eigenvalues"], by_files["eigenvalues"], rtol=1e-6)
    assert by_spectra["vertex_confidence"] is None  # no part was placed in this request
    # the tokens carry each vertex's covered share in sixteenths: coverage within rounding
    assert by_spectra["part_coverage"] == pytest.approx(by_files["part_coverage"], abs=0.02)
    chained = {"spectra": json.dumps([by_spectra["eigenvalues"]]), "regions": json.dumps([by_spectra["region_token"]])}
    again = chain_client.post("/v1/localize", data=chained).json()
    assert again["vertices"] == by_files["vertices"]
    assert again["part_coverage"] == pytest.approx(by_files["part_coverage"], abs=0.02)


@pytest.mark.parametrize(
    ("regions", "detail"),
    [
        ("not json", "regions"),
        ('["fp1.AAAA"]', "regions[0]"),
        ('["region3:!!!.AAAA"]', "regions[0]"),
        ('["region3:AAAA.AAAA"]', "regions[0]"),
        ("[]", "one per spectra operand"),
    ],
)
def test_bad_regions_get_a_problem_naming_them(client, regions, detail):
    form = {"spectra": json.dumps([[1.0 + i for i in range(20)]]), "regions": regions}
    answer = client.post("/v1/localize", data=form)
    assert answer.status_code == 422
    assert answer.json()["type"] == "/problems/invalid-region" and detail in answer.json()["detail"]


def test_a_token_is_read_only_beside_the_spectrum_it_was_issued_for(client, samples):
    """Tokens swapped between two placed parts, an unsigned one of an earlier format and one with a
    changed byte are each refused (422 untrusted-region), not read as another part's region."""
    first, second = [correspond(client, name, data).json() for name, data in samples.items()][:2]
    spectra = json.dumps([first["eigenvalues"], second["eigenvalues"]])
    token = first["region"]["token"]
    body, _, tag = token.partition(".")
    changed = body[:-2] + ("A" if body[-2] != "A" else "B") + body[-1] + "." + tag
    cases = {
        "another part's spectrum": [second["region"]["token"], first["region"]["token"]],
        "earlier format": ["region2:" + token.removeprefix("region3:"), second["region"]["token"]],
        "altered or forged": [changed, second["region"]["token"]],
    }
    for reason, regions in cases.items():
        answer = client.post("/v1/localize", data={"spectra": spectra, "regions": json.dumps(regions)})
        assert answer.status_code == 422, reason
        assert answer.json()["type"] == "/problems/untrusted-region" and reason in answer.json()["detail"]
    kept = client.post(
        "/v1/localize", data={"spectra": spectra, "regions": json.dumps([token, second["region"]["token"]])}
    )
    assert kept.status_code == 200 and kept.json()["located_by"] == "correspondence"


@pytest.mark.parametrize("tell_below", [0.0, 1.01])
def test_a_measured_overlap_is_told_only_below_the_graphs_threshold(chain_client, samples, tell_below):
    """Below the threshold the union is the one told the measured shares; at or above it, the
    untold one (the shares still returned)."""
    correspondence = chain_client.app.state.resources.require_models().correspondence
    kept, correspondence.tell_below = correspondence.tell_below, tell_below
    try:
        files = [("files", (name, data)) for name, data in samples.items()]
        measured = chain_client.post("/v1/union", files=files).json()
    finally:
        correspondence.tell_below = kept
    spectra = json.dumps([operand["eigenvalues"] for operand in measured["operands"]])
    told = tell_below > measured["overlaps"][0]
    assert measured["overlaps_told"] == [told]
    params = {"overlap": str(measured["overlaps"][0])} if told else {}
    if told and measured["boundaries"]:
        params["boundary"] = str(measured["boundaries"][0])
    by_spectra = chain_client.post("/v1/union", params=params, data={"spectra": spectra}).json()
    np.testing.assert_allclose(measured["eigenvalues"], by_spectra["eigenvalues"], rtol=1e-6)


@pytest.mark.parametrize("nested_below", [0.0, 1.01])
def test_a_part_twice_is_told_nested_only_below_the_graphs_confidence_threshold(chain_client, samples, nested_below):
    """A part united with itself could lie inside itself (equal spectra); told nested where its
    place confidence is below the threshold (every confidence is below 1.01), the union is the
    one told overlap 1, and the part itself (idempotence); the measured shares are still
    returned."""
    correspondence = chain_client.app.state.resources.require_models().correspondence
    kept, correspondence.nested_below = correspondence.nested_below, nested_below
    name = "no_head_neck.ply"
    try:
        twice = chain_client.post("/v1/union", files=[("files", (name, samples[name]))] * 2).json()
    finally:
        correspondence.nested_below = kept
    nested = nested_below > 1
    assert twice["overlaps_nested"] == [nested] and twice["overlaps_from"] == "correspondence"
    assert twice["overlaps_told"] == [nested or twice["overlaps"][0] < correspondence.tell_below]
    if nested:
        spectra = json.dumps([operand["eigenvalues"] for operand in twice["operands"]])
        params = {"overlap": "1"} | ({"boundary": str(twice["boundaries"][0])} if twice["boundaries"] else {})
        by_spectra = chain_client.post("/v1/union", params=params, data={"spectra": spectra}).json()
        np.testing.assert_allclose(twice["eigenvalues"], by_spectra["eigenvalues"], rtol=1e-6)
        part = np.asarray(twice["operands"][0]["eigenvalues"])
        np.testing.assert_allclose(twice["eigenvalues"], part, rtol=1e-5)


def test_one_upload_is_placed_only_where_its_region_is_answered(client, samples):
    """Placing costs a second eigen-solve: a union route with one upload has no step to measure
    and does not place it; /v1/localize, which answers its region, does."""
    name = "no_head_neck.ply"
    one = [("files", (name, samples[name]))]
    union = client.post("/v1/union", files=one).json()
    assert union["overlaps_from"] is None and union["overlaps"] == []
    assert client.post("/v1/localize", files=one).json()["located_by"] == "correspondence"


def test_an_upload_beside_a_spectrum_sent_with_its_region_is_placed_as_both_uploads(chain_client, samples):
    """A session's next scan uploaded beside the earlier one's spectrum and region token: the same
    region and union as both uploaded together."""
    (first, data_a), (second, data_b) = samples.items()
    earlier = correspond(chain_client, second, data_b).json()
    form = {"spectra": json.dumps([earlier["eigenvalues"]]), "regions": json.dumps([earlier["region"]["token"]])}
    mixed = chain_client.post("/v1/localize", files=[("files", (first, data_a))], data=form)
    assert mixed.status_code == 200, mixed.text
    both = chain_client.post("/v1/localize", files=[("files", (name, data)) for name, data in samples.items()]).json()
    assert mixed.json()["located_by"] == "correspondence" and mixed.json()["vertices"] == both["vertices"]
    assert mixed.json()["overlaps"] == pytest.approx(both["overlaps"])
    np.testing.assert_allclose(mixed.json()["eigenvalues"], both["eigenvalues"], rtol=1e-6)


class _NoGraphHere:
    """Stands in for the API process's own graph: placing there is what must not happen."""

    def run(self, inputs):
        raise AssertionError("the correspondence graph ran in the API process")


def test_uploads_are_placed_in_the_solver_worker_not_the_api_process(chain_client, samples, monkeypatch):
    """The graph's memory and time fall under a solver worker's cap and deadline: with the API
    process's own graph unusable, a part is still placed, and a union of two still measured."""
    monkeypatch.setattr(chain_client.app.state.resources.require_models().correspondence, "graph", _NoGraphHere())
    name = "no_head_neck.ply"
    placed = correspond(chain_client, name, samples[name])
    assert placed.status_code == 200, placed.text
    files = [("files", (n, samples[n])) for n in PARTS]
    united = chain_client.post("/v1/union", files=files)
    assert united.status_code == 200, united.text
    assert united.json()["overlaps_from"] == "correspondence"


def test_a_part_in_the_wrong_units_is_not_placed_but_its_spectrum_is_answered(client, samples):
    """A body part in metres sent as millimetres (a millionth of its area) is refused by the
    placing routes, naming the unit that fits; its spectrum alone is still answered, warned."""
    name, data = next(iter(samples.items()))
    placed = correspond(client, name, data, units="mm")
    assert placed.status_code == 422 and placed.json()["type"] == "/problems/implausible-size"
    assert "(units=m)" in placed.json()["detail"]
    files = [("files", (n, d)) for n, d in samples.items()]
    united = client.post("/v1/union", params={"units": "mm"}, files=files)
    assert united.status_code == 422 and united.json()["type"] == "/problems/implausible-size"
    spectrum = client.post("/v1/spectrum", params={"units": "mm"}, files={"file": (name, data)})
    assert spectrum.status_code == 200 and any("units=m" in w for w in spectrum.json()["warnings"])


def test_coverage_alone_is_the_full_answer_without_its_per_vertex_arrays(client, samples):
    """detail=coverage: the same answer less every per-vertex array (absent, not empty), a small
    fraction of its size."""
    name, data = next(iter(samples.items()))
    full = correspond(client, name, data)
    short = correspond(client, name, data, detail="coverage")
    assert short.status_code == 200 and len(short.content) * 10 < len(full.content)
    whole, brief = full.json(), short.json()
    for field in ("vertex_indices", "template_vertex", "position", "confidence"):
        assert field not in brief and field in whole
    assert "vertices" not in brief["region"]
    assert brief["region"]["part_coverage"] == whole["region"]["part_coverage"]
    assert brief["region"]["token"] == whole["region"]["token"] and brief["warnings"] == whole["warnings"]
    files = [("files", (n, d)) for n, d in samples.items()]
    located, brief = (
        client.post("/v1/localize", files=files).json(),
        client.post("/v1/localize", files=files, params={"detail": "coverage"}).json(),
    )
    assert "vertices" not in brief and "vertex_confidence" not in brief
    assert brief["part_coverage"] == located["part_coverage"] and brief["eigenvalues"] == located["eigenvalues"]
    assert_problem(correspond(client, name, data, detail="vertices"), 422, "invalid-request")
