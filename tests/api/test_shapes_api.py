"""``/v1/shapes`` and ``/v1/retrieve`` on a real SQLite file: keys, paging, durability, ranking."""

import io
import json

import numpy as np
import pytest
import trimesh
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.inference.template import Template
from app.main import create_app
from app.retrieval.seed import SEED_FILE
from tests.api.conftest import API_KEY, settings_for


def body_ply(scale: float) -> bytes:
    """The template body uniformly scaled: a different 'identity' with a known spectrum ratio."""
    template = Template.load(Settings().models_dir)
    return trimesh.Trimesh(template.vertices * scale, template.faces, process=False).export(file_type="ply")


@pytest.fixture(scope="module")
def empty_client(tmp_path_factory):
    """An app whose store starts empty (no seed), to count exactly what the tests add."""
    models = tmp_path_factory.mktemp("models")
    source = Settings().models_dir
    for path in source.iterdir():
        if path.name != SEED_FILE and path.is_file():
            (models / path.name).write_bytes(path.read_bytes())
    settings = settings_for(tmp_path_factory.mktemp("db") / "shapes.sqlite").model_copy(update={"models_dir": models})
    with TestClient(create_app(settings)) as client:
        yield client, settings


def add(client, label: str, scale: float, key: str | None = API_KEY):
    headers = {"X-API-Key": key} if key is not None else {}
    files = {"file": (f"{label}.ply", io.BytesIO(body_ply(scale)), "application/octet-stream")}
    return client.post("/v1/shapes", data={"label": label}, files=files, headers=headers)


@pytest.fixture(scope="module")
def stored(empty_client):
    client, _ = empty_client
    records = {}
    for label, scale in (("small", 0.9), ("medium", 1.0), ("large", 1.15)):
        response = add(client, label, scale)
        assert response.status_code == 201, response.text
        records[label] = response.json()
    return records


def test_a_closed_body_is_stored_with_its_plain_spectrum(stored):
    spectrum = stored["medium"]["spectrum"]
    assert len(spectrum) == 20 and abs(spectrum[0]) < 1e-6 and spectrum[1] > 0


def test_a_body_is_stored_with_its_body_and_a_ball_without(empty_client, stored):
    """A person's scan keeps the body fitted to it (what identity ranks by); a 10 cm ball, which no
    body passes through, is stored by its spectrum alone."""
    client, _ = empty_client
    assert stored["medium"]["body_fitted"] is True
    ball = trimesh.creation.icosphere(subdivisions=4, radius=0.1).export(file_type="ply")
    answer = client.post(
        "/v1/shapes", data={"label": "ball"}, files={"file": ("ball.ply", ball)}, headers={"X-API-Key": API_KEY}
    )
    assert answer.status_code == 201 and answer.json()["body_fitted"] is False
    assert client.delete(f"/v1/shapes/{answer.json()['id']}", headers={"X-API-Key": API_KEY}).status_code == 204


def test_scaling_a_body_scales_its_stored_spectrum(stored):
    ratio = np.array(stored["small"]["spectrum"][1:]) / np.array(stored["medium"]["spectrum"][1:])
    np.testing.assert_allclose(ratio, 1 / 0.9**2, rtol=1e-6)


@pytest.mark.parametrize("key, status", [(None, 401), ("wrong", 401)])
def test_writes_need_the_key(empty_client, stored, key, status):
    client, _ = empty_client
    response = add(client, "intruder", 1.0, key=key)
    assert response.status_code == status
    assert response.headers["content-type"].startswith("application/problem+json")
    assert client.delete(f"/v1/shapes/{stored['small']['id']}", headers={"X-API-Key": "wrong"}).status_code == 401


def test_retrieval_ranks_the_same_body_first(empty_client, stored):
    client, _ = empty_client
    query = json.dumps([stored["large"]["spectrum"]])
    response = client.post("/v1/retrieve?top=2", data={"spectra": query})
    assert response.status_code == 200, response.text
    matches = response.json()["matches"]
    assert [m["label"] for m in matches] == ["large", "medium"]
    assert matches[0]["distance"] < 1e-9 < matches[1]["distance"]


def test_listing_pages_and_deleting(empty_client, stored, tmp_path):
    client, settings = empty_client
    first = client.get("/v1/shapes?limit=2").json()
    rest = client.get("/v1/shapes?offset=2&limit=2").json()
    assert first["total"] == 3 and len(first["shapes"]) == 2 and len(rest["shapes"]) == 1
    listed = {s["id"] for s in first["shapes"] + rest["shapes"]}
    assert listed == {r["id"] for r in stored.values()}
    extra = add(client, "temporary", 1.3).json()
    assert client.delete(f"/v1/shapes/{extra['id']}", headers={"X-API-Key": API_KEY}).status_code == 204
    assert client.delete(f"/v1/shapes/{extra['id']}", headers={"X-API-Key": API_KEY}).status_code == 404
    # An acknowledged write is on disk: a fresh app on the same file sees it.
    with TestClient(create_app(settings)) as again:
        assert again.get("/v1/shapes").json()["total"] == 3


def test_without_a_configured_key_writes_are_refused(tmp_path):
    settings = Settings(database_path=tmp_path / "s.sqlite", api_key=None)
    with TestClient(create_app(settings)) as client:
        response = add(client, "someone", 1.0, key="anything")
        assert response.status_code == 403
        assert response.json()["type"] == "/problems/writes-disabled"
