"""An acknowledged write (a stored shape, a session's view) survives ``kill -9`` of the server right
after the response, on both engines."""

import contextlib
import signal
import threading
import time

import httpx
import numpy as np
import psycopg
import pytest

from app.core.config import Settings
from app.inference.template import Template
from app.samples import SESSION_SCANS, kept_part
from harness.postgres import free_port
from harness.servers import start, wait_ready
from tests.api.conftest import API_KEY
from tests.api.test_shapes_api import body_ply

BURST = 8


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


def _slow_chunked_upload(base: str, stop: threading.Event) -> None:
    """A body over Starlette's 1 MiB in-memory spool, trickled so it is half-received at the kill."""
    head = b'--cut\r\nContent-Disposition: form-data; name="file"; filename="slow.ply"\r\n\r\n'

    def body():
        yield head
        while not stop.is_set():
            yield b"0" * 262_144
            time.sleep(0.05)

    headers = {"content-type": "multipart/form-data; boundary=cut", "X-API-Key": API_KEY}
    with contextlib.suppress(httpx.HTTPError):
        httpx.post(f"{base}/v1/shapes", content=body(), headers=headers, timeout=30)


def _every_shape(base: str) -> list[dict]:
    shapes: list[dict] = []
    total = 1
    while len(shapes) < total:
        page = httpx.get(f"{base}/v1/shapes", params={"offset": len(shapes), "limit": 500}, timeout=30).json()
        shapes, total = shapes + page["shapes"], page["total"]
    return shapes


def _recorded(errors: list[BaseException], target, *args) -> threading.Thread:
    """A thread whose exception is kept for the test to fail on, not printed and forgotten."""

    def run() -> None:
        try:
            target(*args)
        except BaseException as exc:  # noqa: BLE001 — every failure must reach the test
            errors.append(exc)

    return threading.Thread(target=run)


def test_a_kill_mid_burst_leaves_whole_rows_only_and_no_spooled_file(database, tmp_path):
    spool = tmp_path / "spool"
    spool.mkdir()
    # Built here, not in the threads: numpy's loader is not thread-safe in every release (a
    # thread once died inside np.load, and the test passed without its request).
    bodies = [body_ply(0.9 + 0.02 * index) for index in range(BURST)]
    process, base = served({**database, "TMPDIR": str(spool)})
    at_start = sorted(spool.rglob("*"))  # what start-up itself leaves (onnxruntime, multiprocessing)
    acknowledged: list[str] = []
    errors: list[BaseException] = []
    stop = threading.Event()

    def add(index: int) -> None:
        files = {"file": ("body.ply", bodies[index], "application/octet-stream")}
        with contextlib.suppress(httpx.HTTPError):  # the kill cuts connections: expected, nothing else is
            response = httpx.post(
                f"{base}/v1/shapes", files=files, data={"label": f"burst-{index}"}, headers={"X-API-Key": API_KEY}
            )
            if response.status_code == 201:
                acknowledged.append(response.json()["id"])

    clients = [_recorded(errors, add, i) for i in range(BURST)]
    clients.append(_recorded(errors, _slow_chunked_upload, base, stop))
    try:
        for client in clients:
            client.start()
        time.sleep(1.5)  # some adds acknowledged, others mid-solve, the trickle mid-body
        process.send_signal(signal.SIGKILL)
        process.wait(timeout=10)
    finally:
        stop.set()
        process.kill()
        for client in clients:
            client.join(timeout=30)
    assert not errors, errors
    assert not any(client.is_alive() for client in clients)
    assert sorted(spool.rglob("*")) == at_start  # spooled uploads are anonymous files: none left behind
    process, base = served(database)
    try:
        stored = _every_shape(base)
    finally:
        process.terminate()
        process.wait(timeout=20)
    burst = [shape for shape in stored if shape["label"].startswith("burst-")]
    assert set(acknowledged) <= {shape["id"] for shape in burst}  # nothing acknowledged was lost
    assert len(burst) <= BURST
    for shape in burst:  # and whatever is there is whole
        spectrum = np.asarray(shape["spectrum"])
        assert spectrum.shape == (20,) and np.all(np.isfinite(spectrum)) and np.all(np.diff(spectrum) >= 0)


def test_views_posted_at_once_to_a_session_all_land_and_survive_a_kill_9(database):
    """A front-end's views posted together: each one answered 201 is in the session after the
    server is killed mid-burst and started again, once, whatever the others did."""
    template = Template.load(Settings().models_dir)
    scans = [kept_part(template, kept) for kept in SESSION_SCANS.values()]
    process, base = served(database)
    acknowledged: list[str] = []
    errors: list[BaseException] = []
    session = httpx.post(f"{base}/v1/sessions", timeout=30).json()["id"]

    def add(index: int) -> None:
        files = {"file": (f"view-{index}.ply", scans[index % len(scans)], "application/octet-stream")}
        with contextlib.suppress(httpx.HTTPError):  # the kill cuts connections: expected, nothing else is
            response = httpx.post(f"{base}/v1/sessions/{session}/views", files=files, timeout=60)
            if response.status_code == 201:
                acknowledged.append(f"view-{index}.ply")

    clients = [_recorded(errors, add, index) for index in range(BURST)]
    try:
        for client in clients:
            client.start()
        deadline = time.monotonic() + 60
        while len(acknowledged) < BURST // 2 and time.monotonic() < deadline:
            time.sleep(0.05)
        process.send_signal(signal.SIGKILL)  # some views acknowledged, others mid-solve
        process.wait(timeout=10)
    finally:
        process.kill()
        for client in clients:
            client.join(timeout=30)
    assert not errors, errors
    assert len(acknowledged) >= BURST // 2
    process, base = served(database)
    try:
        stored = httpx.get(f"{base}/v1/sessions/{session}", timeout=60).json()
    finally:
        process.terminate()
        process.wait(timeout=20)
    sources = [view["source"] for view in stored["views"]]
    assert set(acknowledged) <= set(sources) and len(sources) == len(set(sources))
    assert [view["index"] for view in stored["views"]] == list(range(len(sources)))
