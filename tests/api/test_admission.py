"""Upload requests are admitted or refused on their headers, whole, and a stalled body times out.

A real server on loopback and raw sockets, because what is checked is what happens before a
body arrives: a client that has sent only its headers gets its 503, and one that stops halfway
through its body gets a 408 and gives its place back.
"""

import json
import socket
import time

import httpx
import numpy as np
import pytest

from harness.servers import serving
from tests.api.test_backpressure import patch_ply

BODY_TIMEOUT_S = 5
CAPACITY = 2  # one solve slot and one waiting place


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    yield from serving(
        tmp_path_factory.mktemp("db"),
        SPECTRAL_UNIONS_MAX_QUEUED_SOLVES=str(CAPACITY - 1),
        SPECTRAL_UNIONS_BODY_TIMEOUT_SECONDS=str(BODY_TIMEOUT_S),
    )


def _stalled_upload(port: int, path: str = "/v1/spectrum", body: bytes = b"--b\r\n") -> socket.socket:
    """A multipart POST that declares 100 kB and sends its headers and ``body`` only."""
    connection = socket.create_connection(("127.0.0.1", port), timeout=30)
    head = (
        f"POST {path} HTTP/1.1\r\nHost: test\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        "Content-Length: 100000\r\n\r\n"
    )
    connection.sendall(head.encode() + body)
    return connection


def _response(connection: socket.socket) -> tuple[int, dict[str, str], str]:
    """Status, headers and body of the one response on ``connection`` (read until it closes or is whole)."""
    data = b""
    while b"\r\n\r\n" not in data:
        chunk = connection.recv(65536)
        if not chunk:
            break
        data += chunk
    head, _, body = data.partition(b"\r\n\r\n")
    lines = head.decode().split("\r\n")
    headers = {k.lower(): v.strip() for k, _, v in (line.partition(":") for line in lines[1:])}
    while len(body) < int(headers.get("content-length", 0)):
        body += connection.recv(65536)
    return int(lines[0].split()[1]), headers, body.decode()


def _metric(port: int, name: str) -> float:
    text = httpx.get(f"http://127.0.0.1:{port}/metrics").text
    return float(next(line for line in text.splitlines() if line.startswith(name + " ")).split()[1])


def _solves(port: int) -> float:
    return _metric(port, "spectral_unions_solve_seconds_count")


def _held(port: int, count: int) -> list[socket.socket]:
    """``count`` stalled uploads, returned once the server has counted every one of them in."""
    holders = [_stalled_upload(port) for _ in range(count)]
    deadline = time.monotonic() + 30
    while _metric(port, "spectral_unions_upload_requests_in_flight") < count and time.monotonic() < deadline:
        time.sleep(0.02)
    return holders


def _release(port: int, holders: list[socket.socket]) -> None:
    """Close the stalled uploads and wait until the server has given their places back."""
    for holder in holders:
        holder.close()
    deadline = time.monotonic() + 30
    while _metric(port, "spectral_unions_upload_requests_in_flight") > 0 and time.monotonic() < deadline:
        time.sleep(0.02)


def test_an_upload_beyond_capacity_is_refused_on_its_headers_without_its_body(server):
    holders = _held(server, CAPACITY)
    try:
        late = _stalled_upload(server, body=b"")  # headers only: not one byte of its body is sent
        status, headers, body = _response(late)
        assert status == 503, body
        assert headers["content-type"] == "application/problem+json"
        assert headers["retry-after"] == "1"
        assert '"/problems/overloaded"' in body
    finally:
        _release(server, holders)
    response = httpx.post(f"http://127.0.0.1:{server}/v1/spectrum", files={"file": ("p.ply", patch_ply())})
    assert response.status_code == 200, response.text  # the closed holders gave their places back


def test_a_two_file_union_is_refused_whole_before_any_of_its_files_is_solved(server):
    holders = _held(server, CAPACITY)
    try:
        before = _solves(server)
        files = [("files", ("a.ply", patch_ply())), ("files", ("b.ply", patch_ply()))]
        response = httpx.post(f"http://127.0.0.1:{server}/v1/union", files=files)
        assert response.status_code == 503, response.text
        assert response.json()["type"] == "/problems/overloaded"
        assert _solves(server) == before
    finally:
        _release(server, holders)
    response = httpx.post(f"http://127.0.0.1:{server}/v1/union", files=files)
    assert response.status_code == 200, response.text
    assert _solves(server) == before + 2


def test_a_body_that_stalls_is_answered_408_and_its_place_is_freed(server):
    stalled = _stalled_upload(server)
    status, headers, body = _response(stalled)
    stalled.close()
    assert status == 408, body
    assert '"/problems/body-timeout"' in body and "(5 bytes received)" in body
    assert headers["connection"] == "close"
    holders = _held(server, CAPACITY - 1)
    try:
        response = httpx.post(f"http://127.0.0.1:{server}/v1/spectrum", files={"file": ("p.ply", patch_ply())})
        assert response.status_code == 200, response.text
    finally:
        _release(server, holders)


@pytest.mark.parametrize("route", ["/v1/reconstruct", "/v1/retrieve"])
def test_a_route_that_may_solve_is_counted_in_even_with_url_encoded_spectra(server, route):
    """/v1/reconstruct solves the body it rebuilt whatever its body holds, /v1/retrieve the body
    rebuilt from an open surface (this spectrum's λ₁ > 0): with every place taken each is refused
    on its headers, while a spectra-only union (no solve) still passes."""
    spectra = {"spectra": json.dumps([np.cumsum(np.linspace(0.5, 4, 20)).tolist()])}  # λ₁ = 0.5, λ₂ = 1.2: open
    holders = _held(server, CAPACITY)
    try:
        before = _solves(server)
        refused = httpx.post(f"http://127.0.0.1:{server}{route}", data=spectra, timeout=30)
        assert refused.status_code == 503 and refused.json()["type"] == "/problems/overloaded", refused.text
        assert httpx.post(f"http://127.0.0.1:{server}/v1/union", data=spectra, timeout=30).status_code == 200
        assert _solves(server) == before
    finally:
        _release(server, holders)
    answered = httpx.post(f"http://127.0.0.1:{server}{route}", data=spectra, timeout=60)
    assert answered.status_code == 200, answered.text
    assert _solves(server) == before + 1


@pytest.fixture(scope="module")
def budgeted_server(tmp_path_factory):
    """Room for four uploads, and bytes in flight for one body of the upload cap and a half."""
    yield from serving(
        tmp_path_factory.mktemp("db"),
        SPECTRAL_UNIONS_BODY_TIMEOUT_SECONDS=str(BODY_TIMEOUT_S),
        SPECTRAL_UNIONS_MAX_QUEUED_SOLVES="3",
        SPECTRAL_UNIONS_MAX_INFLIGHT_UPLOAD_BYTES=str(96 * 1024 * 1024),
    )


def _trickle(port: int) -> socket.socket:
    """A chunked multipart POST (no declared length) that has sent one byte of its body."""
    connection = socket.create_connection(("127.0.0.1", port), timeout=30)
    head = (
        "POST /v1/spectrum HTTP/1.1\r\nHost: test\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        "Transfer-Encoding: chunked\r\n\r\n1\r\n-\r\n"
    )
    connection.sendall(head.encode())
    return connection


def test_slow_bodies_are_charged_what_they_sent_not_the_upload_cap(budgeted_server):
    """Each chunked body was charged the 64 MiB cap on admission: two that trickled held the
    budget, and every other upload was refused until they timed out. Charged as their bytes
    arrive, both are admitted and an honest upload beside them is answered."""
    port = budgeted_server
    holders = [_trickle(port) for _ in range(2)]
    try:
        deadline = time.monotonic() + 30
        while _metric(port, "spectral_unions_upload_requests_in_flight") < 2 and time.monotonic() < deadline:
            time.sleep(0.02)
        assert _metric(port, "spectral_unions_upload_requests_in_flight") == 2
        assert _metric(port, "spectral_unions_upload_bytes_in_flight") <= 2 * 1024 * 1024
        response = httpx.post(f"http://127.0.0.1:{port}/v1/spectrum", files={"file": ("p.ply", patch_ply())})
        assert response.status_code == 200, response.text
    finally:
        _release(port, holders)
    assert _metric(port, "spectral_unions_upload_bytes_in_flight") == 0
