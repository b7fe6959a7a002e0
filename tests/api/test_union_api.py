"""``/v1/union``, ``/v1/localize`` and ``/v1/models`` on the committed ONNX models."""

import io
import json

import numpy as np
import pytest
import trimesh

from app.contract import SESSIONS_FILE
from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from app.geometry.topology import drop_unreferenced
from app.inference.template import PART_NAMES, Template
from app.sessions.calibration import SessionCalibration

PROBLEM = "application/problem+json"
LEGS = ("left_thigh", "right_thigh", "left_shin", "right_shin", "left_foot", "right_foot")
HEAD_AND_ARMS = ("head", "neck", "left_upper_arm", "right_upper_arm", "left_hand", "right_hand")


def region(template: Template, removed: tuple[str, ...]) -> Mesh:
    """The template with some body parts cut away."""
    keep = ~np.isin(template.labels, [PART_NAMES.index(p) for p in removed])
    return Mesh(*drop_unreferenced(template.vertices, template.faces[keep[template.faces].all(axis=1)]))


def spectrum(mesh: Mesh) -> list[float]:
    return list(mesh_spectrum(mesh, SpectrumOptions(k=20)).eigenvalues)


def ply_bytes(mesh: Mesh) -> bytes:
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type="ply")


@pytest.fixture(scope="module")
def parts(template):
    return (
        spectrum(region(template, LEGS)),
        spectrum(region(template, HEAD_AND_ARMS)),
        spectrum(region(template, ("left_upper_arm", "left_forearm", "left_hand"))),
    )


def union(client, spectra, files=None):
    return client.post("/v1/union", data={"spectra": json.dumps(spectra)}, files=files)


def test_union_is_commutative_monotone_and_inside_its_interval(client, parts):
    upper, lower, _ = parts
    ab, ba = union(client, [upper, lower]), union(client, [lower, upper])
    assert ab.status_code == 200, ab.text
    for key in ("eigenvalues", "sigma", "lower", "upper"):
        assert ab.json()[key] == ba.json()[key]
    body = ab.json()
    values = np.array(body["eigenvalues"])
    assert len(values) == 20 and len(body["operands"]) == 2 and body["union_by"] == "learned-chain"
    assert np.all(np.diff(values) >= 0) and np.all(values >= 0)
    assert np.all(np.array(body["lower"]) <= values) and np.all(values <= np.array(body["upper"]))


def test_three_operands_fold_left_to_right(client, parts):
    upper, lower, no_arm = parts
    chained = union(client, [upper, lower, no_arm]).json()
    inner = union(client, [upper, lower]).json()["eigenvalues"]
    outer = union(client, [inner, no_arm]).json()
    np.testing.assert_allclose(chained["eigenvalues"], outer["eigenvalues"], rtol=1e-6)


def test_one_operand_is_returned_as_is(client, parts):
    body = union(client, [parts[0]]).json()
    np.testing.assert_allclose(body["eigenvalues"], parts[0], rtol=1e-6)
    assert body["sigma"] == [0.0] * 20 and body["union_by"] == "operand"


def test_a_file_operand_is_solved_server_side(client, template, parts):
    mesh = region(template, LEGS)
    files = [("files", ("upper.ply", io.BytesIO(ply_bytes(mesh)), "application/octet-stream"))]
    response = union(client, [parts[1]], files=files)
    assert response.status_code == 200, response.text
    body = response.json()
    assert [o["source"] for o in body["operands"]] == ["files[0] upper.ply", "spectra[0]"]
    np.testing.assert_allclose(body["operands"][0]["eigenvalues"], parts[0], rtol=1e-6)
    np.testing.assert_allclose(
        body["eigenvalues"], union(client, [parts[0], parts[1]]).json()["eigenvalues"], rtol=1e-5
    )


@pytest.mark.parametrize(
    "spectra, says",
    [
        ([], "no operand"),
        ([[1.0] * 20, [1.0] * 19], "spectra[1]"),
        ([[1.0] * 20, [-5.0] + [1.0] * 19], "negative"),
        ([[1.0] * 20, list(range(20, 0, -1))], "ascending"),
        ([[1.0] * 20] * 33, "operands"),
        ([[1.0] * 20, ["a"] * 20], "numbers"),
    ],
)
def test_bad_spectra_are_422_problems_naming_the_operand(client, spectra, says):
    response = union(client, spectra)
    assert response.status_code == 422
    assert response.headers["content-type"].startswith(PROBLEM)
    assert says in response.json()["detail"]


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "1e400", "[1, 2", "{}"])
def test_non_finite_or_malformed_spectra_are_422_problems(client, literal):
    text = "[[" + ",".join(["1.0"] * 19 + [literal]) + "], [" + ",".join(["1.0"] * 20) + "]]"
    response = client.post("/v1/union", data={"spectra": text})
    assert response.status_code == 422
    assert response.headers["content-type"].startswith(PROBLEM)


def test_a_broken_file_operand_is_a_problem_naming_it(client, parts):
    files = [("files", ("scan.ply", io.BytesIO(b"ply\nformat nonsense\n"), "application/octet-stream"))]
    response = union(client, [parts[0]], files=files)
    assert response.status_code == 422
    assert "files[0] scan.ply" in response.json()["detail"]


class MeetingSolver:
    """A solver pool that answers a solve only once ``expected`` solves are in flight together:
    a request that solves its files one after the other never gets an answer (its first solve
    waits for a second that is never asked), and fails on the guard's timeout."""

    def __init__(self, real, expected: int) -> None:
        self.real, self.expected, self.in_flight, self.peak = real, expected, 0, 0

    async def solve_with_functions(self, data, file_type, options, **flags):
        import asyncio

        self.in_flight += 1
        self.peak = max(self.peak, self.in_flight)
        try:
            async with asyncio.timeout(60):  # a deadlock guard, not a measured time
                while self.peak < self.expected:
                    await asyncio.sleep(0.01)
            return await self.real.solve_with_functions(data, file_type, options, **flags)
        finally:
            self.in_flight -= 1


def test_a_request_s_files_are_solved_at_once_and_a_failure_names_the_first_failing_file(client, template, parts):
    real = client.app.state.solver
    meeting = MeetingSolver(real, expected=2)
    client.app.state.solver = meeting
    try:
        body = ply_bytes(region(template, LEGS))
        files = [("files", (name, io.BytesIO(body), "application/octet-stream")) for name in ("a.ply", "b.ply")]
        response = union(client, [], files=files)
        assert response.status_code == 200, response.text
        assert meeting.peak == 2
        np.testing.assert_allclose(
            response.json()["eigenvalues"][:5], union(client, [parts[0]] * 2).json()["eigenvalues"][:5], rtol=1e-5
        )
        broken = io.BytesIO(b"ply\nformat nonsense\n")
        files = [
            ("files", ("fine.ply", io.BytesIO(body), "application/octet-stream")),
            ("files", ("first-bad.ply", broken, "application/octet-stream")),
            ("files", ("second-bad.ply", io.BytesIO(b"ply\nformat nonsense\n"), "application/octet-stream")),
        ]
        meeting.peak, meeting.expected = 0, 3
        response = union(client, [], files=files)
        assert response.status_code == 422 and "files[1] first-bad.ply" in response.json()["detail"]
    finally:
        client.app.state.solver = real


def test_localize_reports_vertices_and_part_coverage(client, parts, template):
    response = client.post("/v1/localize", data={"spectra": json.dumps([parts[2]])})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["template_vertices"] == len(template.vertices)
    vertices = np.array(body["vertices"])
    assert np.all((vertices >= 0) & (vertices < len(template.vertices))) and len(np.unique(vertices)) == len(vertices)
    assert set(body["part_coverage"]) == set(PART_NAMES)
    assert all(0 <= v <= 1 for v in body["part_coverage"].values())
    assert 0 <= body["area_fraction"] <= 1


def test_models_describes_what_is_loaded(client, template):
    body = client.get("/v1/models").json()
    assert body["k"] == 20 and body["template_vertices"] == len(template.vertices)
    assert body["parts"] == list(PART_NAMES) and len(body["model_version"]) == 12
    assert body["database"]["backend"] == "sqlite"
    assert body["database"]["shapes"] == client.get("/v1/shapes").json()["total"] > 0


def test_metrics_count_requests_by_endpoint(client, parts):
    union(client, [parts[0], parts[1]])
    client.delete("/v1/shapes/some-id-that-is-not-there", headers={"X-API-Key": "x"})
    text = client.get("/metrics").text
    assert 'spectral_unions_requests_total{handler="union",method="POST",status="200"}' in text
    assert 'handler="delete_shape",method="DELETE",status="401"' in text and "some-id-that-is-not-there" not in text
    assert 'spectral_unions_inference_seconds_count{model="union"}' in text


def test_made_up_http_methods_do_not_grow_the_metrics(client):
    """uvicorn passes any method token through; each one used to become a new series."""
    for index in range(40):
        assert client.request(f"BREW{index}", "/v1/models").status_code == 405
    text = client.get("/metrics").text
    assert "BREW" not in text
    line = next(line for line in text.splitlines() if 'method="other",status="405"' in line)
    assert float(line.split()[-1]) >= 40


def test_localize_as_ply_colours_the_region(client, parts, template):
    spectra = {"spectra": json.dumps([parts[2]])}
    region = client.post("/v1/localize", data=spectra).json()["vertices"]
    response = client.post("/v1/localize?format=ply", data=spectra)
    assert response.status_code == 200 and response.headers["content-type"] == "application/ply"
    mesh = trimesh.load(io.BytesIO(response.content), file_type="ply", process=False)
    assert len(mesh.vertices) == len(template.vertices) and len(mesh.faces) == len(template.faces)
    red = np.flatnonzero(mesh.visual.vertex_colors[:, 0] > 210)
    np.testing.assert_array_equal(red, region)


def test_a_localized_union_holds_each_operand_s_own_region(client, parts, template):
    """The union's region holds its operands' regions, each on the union's side (a region is
    known only up to left/right), and the union's own localization: a union contains its
    parts. Symmetric in the operands, like the union."""

    def localized(spectra: list[list[float]]) -> set[int]:
        response = client.post("/v1/localize", data={"spectra": json.dumps(spectra)})
        assert response.status_code == 200, response.text
        return set(response.json()["vertices"])

    both = localized([parts[1], parts[2]])
    assert both == localized([parts[2], parts[1]])
    union_alone = localized([union(client, [parts[1], parts[2]]).json()["eigenvalues"]])
    assert union_alone <= both
    for part in parts[1:]:
        own = np.zeros(len(template.vertices), bool)
        own[list(localized([part]))] = True
        sides = {frozenset(np.flatnonzero(own)), frozenset(np.flatnonzero(own[template.mirror]))}
        assert any(side <= both for side in sides)
    # Not the whole body, so the holding is not vacuous; here the parts add to the union's own
    # region (measured: 9 986 → 10 022 vertices of 12 167).
    assert len(union_alone) < len(both) < len(template.vertices)


def test_a_union_of_uploads_is_read_from_their_geometry(client, template):
    """Every operand an upload: the union is read from the uploads themselves, as a session reads
    its views. The template without its legs and the template without head and neck cover the
    whole body between them, so their union is the closed body: registered (one frame, one
    pose) they are fused and solved once, in either order one answer; in frames of their own they
    are aligned through their places first, or folded where the calibration chose the chain;
    their spectra alone are folded by the learned operator."""
    closed = mesh_spectrum(Mesh(template.vertices, template.faces), SpectrumOptions(k=20)).eigenvalues

    def error(values: list[float]) -> float:  # mean relative error past λ₁ = 0; a point cloud's floor is ~3 %
        return float((np.abs(np.array(values) - closed) / closed)[1:].mean())

    meshes = [region(template, LEGS), region(template, ("head", "neck"))]
    files = [("files", (f"part{i}.ply", ply_bytes(mesh))) for i, mesh in enumerate(meshes)]
    fused = client.post("/v1/union", params={"measure_overlap": "true"}, files=files).json()
    assert fused["union_by"] == "fused"
    assert fused["eigenvalues"][0] < 1e-6 and fused["sigma"][1] > 0  # closed: λ₁ = 0, as the body's
    assert error(fused["eigenvalues"]) < 0.04
    backward = client.post("/v1/union", params={"measure_overlap": "true"}, files=files[::-1]).json()
    assert backward["eigenvalues"] == fused["eigenvalues"]
    own_frames = client.post("/v1/union", files=files).json()
    reading = SessionCalibration.load(Settings().models_dir / SESSIONS_FILE, 20).unregistered_by(2)
    assert own_frames["union_by"] == reading
    if reading == "aligned":
        assert error(own_frames["eigenvalues"]) < 0.04
    spectra = [operand["eigenvalues"] for operand in fused["operands"]]
    assert union(client, spectra).json()["union_by"] == "learned-chain"
