"""An acknowledged write survives ``kill -9`` of the server right after the response, on both engines."""

import signal

import httpx
import psycopg
import pytest

from tests.api.conftest import API_KEY
from tests.api.servers import start, wait_ready
from tests.api.test_shapes_api import body_ply
from tests.postgres import free_port


@pytest.fixture(params=["sqlite", "postgresql"])
def database(request, tmp_path) -> dict[str, str]:
    if request.param == "sqlite":
        return {"SPECTRAL_UNIONS_DATABASE_PATH": str(tmp_path / "shapes.sqlite")}
    url = request.getfixturevalue("postgres_url")
    with psycopg.connect(url, autocommit=True) as connection:
        connection.execute("DROP TABLE IF EXISTS shapes")
    return {"SPECTRAL_UNIONS_DATABASE_URL": url}


def served(database: dict[str, str]):
    port = free_port()
    process = start(port, database)
    base = f"http://127.0.0.1:{port}"
    wait_ready(base, process)
    return process, base


def test_an_acknowledged_shape_survives_a_kill_9(database):
    process, base = served(database)
    try:
        files = {"file": ("body.ply", body_ply(0.97), "application/octet-stream")}
        added = httpx.post(
            f"{base}/v1/shapes", files=files, data={"label": "durable"}, headers={"X-API-Key": API_KEY}, timeout=60
        )
        process.send_signal(signal.SIGKILL)  # no shutdown, no flush: straight after the 201
        process.wait(timeout=10)
    finally:
        process.kill()
    assert added.status_code == 201
    process, base = served(database)
    try:
        query = {"spectra": f"[{added.json()['spectrum']}]"}
        found = httpx.post(f"{base}/v1/retrieve", data=query, params={"top": 1}, timeout=60).json()["matches"][0]
    finally:
        process.terminate()
        process.wait(timeout=20)
    assert found["id"] == added.json()["id"] and found["label"] == "durable"
    assert found["distance"] == pytest.approx(0.0, abs=1e-9)
