"""``/v1/sessions``: a session filled one view at a time answers the union of all its views (the
exact union's spectrum for registered views, the learned chain's for the others), its coverage
and what to scan next; a bad view, a full or a missing session are clear problems that leave the
session as it was."""

from dataclasses import replace

import numpy as np
import pytest
import trimesh
from fastapi.testclient import TestClient
from scipy.spatial.transform import Rotation

from app.contract import BODY_FILE, SEED_BODIES_FILE, SESSIONS_FILE
from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.inference.template import PART_NAMES, Template
from app.main import create_app
from app.samples import SESSION_SCANS, template_part
from app.sessions.calibration import SessionCalibration
from tests.api.conftest import API_KEY, settings_for, settings_without
from tests.api.test_union_api import PROBLEM, region

HEAD_SIDE, LEG_SIDE = SESSION_SCANS  # head, torso and left arm; torso, hips and right leg
ALSO_LEFT_LEG = ("torso", "hips", "left_thigh", "left_shin", "left_foot")
MAX_VIEWS = 3


def removed(kept: tuple[str, ...]) -> tuple[str, ...]:
    return tuple(part for part in PART_NAMES if part not in kept)


@pytest.fixture(scope="module")
def scans(template) -> dict[str, bytes]:
    """Three views of the template body in its own frame, each the body without some parts."""
    found = {name: template_part(template, removed(kept)) for name, kept in SESSION_SCANS.items()}
    found["torso_hips_left_leg.ply"] = template_part(template, removed(ALSO_LEFT_LEG))
    return found


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    database = tmp_path_factory.mktemp("db") / "sessions.sqlite"
    settings = settings_for(database).model_copy(update={"session_max_views": MAX_VIEWS})
    with TestClient(create_app(settings)) as test_client:
        yield test_client


def new_session(client, **options) -> dict:
    made = client.post("/v1/sessions", json=options or None)
    assert made.status_code == 201, made.text
    assert made.headers["location"] == f"/v1/sessions/{made.json()['id']}"
    return made.json()


def add(client, session: str, name: str, data: bytes):
    return client.post(f"/v1/sessions/{session}/views", files={"file": (name, data)})


def truth(template: Template, *kept: tuple[str, ...]) -> np.ndarray:
    """The spectrum of the template region the views cover together."""
    together = set().union(*kept)
    return np.asarray(mesh_spectrum(region(template, removed(tuple(together))), SpectrumOptions(k=20)).eigenvalues)


def test_a_new_session_is_empty_and_says_what_to_scan(client):
    session = new_session(client)
    assert session["views"] == [] and session["union_by"] == "empty" and session["eigenvalues"] == []
    assert session["area_fraction"] == 0.0 and set(session["part_coverage"]) == set(PART_NAMES)
    assert len(session["least_covered"]) == 3 and not session["registered"] and session["scale"] == 1.0


def test_one_view_is_its_own_union(client, scans):
    session = new_session(client)["id"]
    answer = add(client, session, HEAD_SIDE, scans[HEAD_SIDE])
    assert answer.status_code == 201, answer.text
    body = answer.json()
    assert body["union_by"] == "view" and body["sigma"] == [0.0] * 20
    assert body["eigenvalues"] == body["views"][0]["eigenvalues"]
    assert body["part_coverage"]["head"] > 0.8 and body["part_coverage"]["right_foot"] < 0.1
    assert "head" not in body["least_covered"]


def test_registered_views_are_fused_into_the_exact_union_in_any_order(client, template, scans):
    answers = []
    for order in ((HEAD_SIDE, LEG_SIDE), (LEG_SIDE, HEAD_SIDE)):
        session = new_session(client, registered=True)["id"]
        for name in order:
            answer = add(client, session, name, scans[name])
            assert answer.status_code == 201, answer.text
        answers.append(answer.json())
    first, second = answers
    assert first["union_by"] == "fused" and first["registered"]
    np.testing.assert_array_equal(first["eigenvalues"], second["eigenvalues"])  # any order: one union
    exact = truth(template, *SESSION_SCANS.values())
    assert np.mean(np.abs(np.array(first["eigenvalues"]) - exact) / exact) < 0.05
    sigma = np.array(first["sigma"])
    assert np.all(sigma > 0) and np.all(np.array(first["lower"]) <= first["eigenvalues"])
    covered = first["part_coverage"]
    assert covered["torso"] > 0.8 and covered["right_thigh"] > 0.8 and covered["left_thigh"] < 0.1
    assert "right_foot" not in first["least_covered"]


def unregistered_reading(views: int) -> str:
    """How the served calibration reads a session of ``views`` unregistered views."""
    models = Settings().models_dir
    return SessionCalibration.load(models / SESSIONS_FILE, 20).unregistered_by(views)


def test_unregistered_views_are_read_as_the_calibration_chose(client, scans):
    session = new_session(client)["id"]
    for name in (HEAD_SIDE, LEG_SIDE):
        answer = add(client, session, name, scans[name])
    body = answer.json()
    assert body["union_by"] == unregistered_reading(2)
    if body["union_by"] == "learned-chain":  # the union route's fold, bit for bit
        files = [("files", (name, scans[name])) for name in (HEAD_SIDE, LEG_SIDE)]
        union = client.post("/v1/union", files=files).json()
        np.testing.assert_allclose(body["eigenvalues"], union["eigenvalues"], rtol=1e-9)
        np.testing.assert_allclose(body["sigma"], union["sigma"], rtol=1e-9)
        assert body["overlaps"] == pytest.approx(union["overlaps"]) and body["overlaps_told"] == union["overlaps_told"]
    else:  # the views were in one frame already: aligned, they are the registered union
        registered = new_session(client, registered=True)["id"]
        for name in (HEAD_SIDE, LEG_SIDE):
            fused = add(client, registered, name, scans[name]).json()
        np.testing.assert_allclose(body["eigenvalues"], fused["eigenvalues"], rtol=5e-3)
    read = client.get(f"/v1/sessions/{session}").json()
    assert read["eigenvalues"] == body["eigenvalues"] and [v["source"] for v in read["views"]] == [HEAD_SIDE, LEG_SIDE]


def test_unregistered_views_may_come_in_frames_of_their_own(client, template):
    """The same two views, the second turned and moved (another scanner frame): the session
    answers as it does for the two in one frame."""
    turned = Rotation.from_euler("zx", [70, 20], degrees=True).as_matrix()
    elsewhere = replace(template, vertices=template.vertices @ turned.T + [0.8, -1.5, 0.3])
    answers = []
    for second in (template, elsewhere):
        session = new_session(client)["id"]
        add(client, session, HEAD_SIDE, template_part(template, removed(SESSION_SCANS[HEAD_SIDE])))
        answer = add(client, session, LEG_SIDE, template_part(second, removed(SESSION_SCANS[LEG_SIDE])))
        answers.append(answer.json())
    one_frame, two_frames = answers
    assert one_frame["union_by"] == two_frames["union_by"]
    np.testing.assert_allclose(two_frames["eigenvalues"], one_frame["eigenvalues"], rtol=5e-3)
    assert two_frames["part_coverage"] == pytest.approx(one_frame["part_coverage"], abs=0.02)


def test_a_bad_view_is_a_problem_and_leaves_the_session_as_it_was(client, scans):
    session = new_session(client)["id"]
    before = add(client, session, HEAD_SIDE, scans[HEAD_SIDE]).json()
    for name, data in (("broken.ply", b"ply\nformat ascii 1.0\nelement vertex 3\nend_header\n1 2\n"), ("x.zip", b"PK")):
        refused = add(client, session, name, data)
        assert 400 <= refused.status_code < 500 and refused.headers["content-type"].startswith(PROBLEM)
    after = client.get(f"/v1/sessions/{session}").json()
    assert after["views"] == before["views"] and after["eigenvalues"] == before["eigenvalues"]


def test_a_full_session_refuses_another_view(client, scans):
    session = new_session(client)["id"]
    for name in list(scans)[:MAX_VIEWS]:
        assert add(client, session, name, scans[name]).status_code == 201
    refused = add(client, session, HEAD_SIDE, scans[HEAD_SIDE])
    assert refused.status_code == 409 and refused.json()["type"] == "/problems/session-full"
    assert len(client.get(f"/v1/sessions/{session}").json()["views"]) == MAX_VIEWS


def test_a_missing_or_ended_session_is_404(client, scans):
    session = new_session(client)["id"]
    assert client.delete(f"/v1/sessions/{session}").status_code == 204
    for response in (
        client.get(f"/v1/sessions/{session}"),
        client.delete(f"/v1/sessions/{session}"),
        add(client, session, HEAD_SIDE, scans[HEAD_SIDE]),
        client.get("/v1/sessions/never-made"),
    ):
        assert response.status_code == 404 and response.json()["type"] == "/problems/session-not-found"


@pytest.mark.parametrize(
    "body", ['{"registered": "perhaps"}', '{"units": "furlong"}', '{"scale": -1}', '{"colour": 1}', "{not json"]
)
def test_malformed_options_are_422_problems(client, body):
    response = client.post("/v1/sessions", content=body, headers={"content-type": "application/json"})
    assert response.status_code == 422 and response.headers["content-type"].startswith(PROBLEM)


def test_units_apply_to_every_view(client, template, scans):
    session = new_session(client, units="mm")["id"]
    millimetres = template_part_in_mm(template)
    body = add(client, session, "head_side_mm.ply", millimetres).json()
    metres = add(client, new_session(client)["id"], HEAD_SIDE, scans[HEAD_SIDE]).json()
    assert body["scale"] == 0.001
    np.testing.assert_allclose(body["eigenvalues"], metres["eigenvalues"], rtol=1e-4)


def template_part_in_mm(template: Template) -> bytes:
    scaled = replace(template, vertices=template.vertices * 1000)
    return template_part(scaled, removed(SESSION_SCANS[HEAD_SIDE]))


def test_a_session_s_body_is_the_body_its_views_saw_and_measures_what_they_support(client, template, scans):
    from app.inference.measurements import Measurer

    session = new_session(client, registered=True)["id"]
    for name in SESSION_SCANS:
        assert add(client, session, name, scans[name]).status_code == 201
    answer = client.get(f"/v1/sessions/{session}/body")
    assert answer.status_code == 200, answer.text
    body = answer.json()
    vertices = np.array(body["vertices"])
    assert vertices.shape == template.vertices.shape and len(body["sigma_m"]) == len(vertices)
    aligned = vertices - vertices.mean(axis=0) + template.vertices.mean(axis=0)
    assert np.linalg.norm(aligned - template.vertices, axis=1).mean() < 0.015  # the views are the template's own
    measured = {m["name"]: m for m in body["measurements"]}
    truth = Measurer.of(template).measure(template.vertices.astype(np.float64))
    assert abs(measured["stature"]["value_m"] - truth["stature"]) < 0.02
    assert all(m["lower_m"] <= m["value_m"] <= m["upper_m"] for m in measured.values())
    # Head, torso and left arm, then torso, hips and right leg: no right arm, so no shoulder breadth.
    assert "shoulder_breadth" in body["not_measured"] and "shoulder_breadth" not in measured
    assert {"crotch_height", "arm_length"} <= set(measured)


def test_a_body_needs_views_and_a_session(client):
    empty = new_session(client, registered=True)["id"]
    answer = client.get(f"/v1/sessions/{empty}/body")
    assert answer.status_code == 409 and answer.headers["content-type"] == PROBLEM
    assert answer.json()["type"].endswith("/body-not-fitted")
    missing = client.get("/v1/sessions/no-such-session/body")
    assert missing.status_code == 404 and missing.json()["type"].endswith("/session-not-found")


def test_scans_cut_from_a_stored_body_find_that_body_first(client, template, scans):
    """The template body stored as a person beside the seed database's 630 shapes; a registered
    session of three scans cut from it answers that person first, once, with the most confidence."""
    whole = trimesh.Trimesh(template.vertices, template.faces, process=False).export(file_type="ply")
    stored = client.post(
        "/v1/shapes",
        data={"label": "scanned-person"},
        files={"file": ("whole.ply", whole)},
        headers={"X-API-Key": API_KEY},
    )
    assert stored.status_code == 201, stored.text
    session = new_session(client, registered=True)["id"]
    for name in (*SESSION_SCANS, "torso_hips_left_leg.ply"):
        assert add(client, session, name, scans[name]).status_code == 201
    answer = client.get(f"/v1/sessions/{session}/identity", params={"top": 5})
    assert answer.status_code == 200, answer.text
    found = answer.json()
    assert found["ranked_by"] == "shape" and found["views"] == 3 and found["looked_up"] is None
    people = found["people"]
    assert people[0]["label"] == "scanned-person" and people[0]["shape_id"] == stored.json()["id"]
    assert len({p["label"] for p in people}) == len(people) == 5  # one answer per person
    confidences = [p["confidence"] for p in people]
    assert confidences == sorted(confidences, reverse=True) and sum(confidences) <= 1 + 1e-9


def test_a_store_without_bodies_is_ranked_by_the_fitted_body_s_spectrum(tmp_path, scans):
    """Seeded without the seed people's bodies, no stored shape has one: identity ranks the stored
    spectra by the fitted body's closed spectrum instead, and says so."""
    with TestClient(create_app(settings_without(tmp_path, SEED_BODIES_FILE))) as bare:
        session = new_session(bare, registered=True)["id"]
        for name in SESSION_SCANS:
            assert add(bare, session, name, scans[name]).status_code == 201
        found = bare.get(f"/v1/sessions/{session}/identity", params={"top": 3}).json()
    assert found["ranked_by"] == "fitted_body" and len(found["looked_up"]) == 20 and len(found["people"]) == 3


def test_a_ball_is_no_body(client):
    """A 10 cm ball is placed somewhere on the template, but no body passes through its points."""
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.1).export(file_type="ply")
    session = new_session(client, registered=True)["id"]
    assert add(client, session, "ball.ply", ball).status_code == 201
    answer = client.get(f"/v1/sessions/{session}/body")
    assert answer.status_code == 409 and answer.json()["type"].endswith("/body-not-fitted")
    assert "do not fit a body" in answer.json()["detail"]


def test_a_ball_covers_nothing_and_a_restart_still_knows_it(client, scans):
    """A ball beside a real view adds no coverage (its places crowd onto a spot: doubted), and
    the view read back from the database is still doubted: its made-up region is not told to the
    union's next step as an overlap of nothing."""
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.1).export(file_type="ply")
    session = new_session(client)["id"]
    alone = add(client, session, HEAD_SIDE, scans[HEAD_SIDE]).json()
    with_ball = add(client, session, "ball.ply", ball).json()
    assert with_ball["part_coverage"] == pytest.approx(alone["part_coverage"])
    assert any("not part of a human body" in w for w in with_ball["views"][1]["warnings"])
    read = client.get(f"/v1/sessions/{session}").json()
    assert read["part_coverage"] == pytest.approx(alone["part_coverage"])
    assert read["overlaps_told"] == [False]


def test_models_without_a_body_basis_say_so(tmp_path, client):
    """The served models fit bodies and say so; a models folder without body.npz (not in its
    manifest) says it does not, and a session's body is a 501 problem there."""
    assert client.get("/v1/models").json()["body"] is True
    settings = settings_without(tmp_path, BODY_FILE)
    with TestClient(create_app(settings)) as bare:
        assert bare.get("/v1/models").json()["body"] is False
        session = bare.post("/v1/sessions", json={"registered": True}).json()["id"]
        answer = bare.get(f"/v1/sessions/{session}/body")
        assert answer.status_code == 501 and answer.json()["type"].endswith("/body-unavailable")
