"""The proxy of ``deploy/`` in front of a real replica: malformed HTTP stops there, in problem+json.

uvicorn answers a request it cannot frame with its own text/plain 400, and accepts one that
carries both Content-Length and Transfer-Encoding; the proxy must refuse those before they
reach a replica. This runs ``deploy/nginx.conf`` itself (its upstream and port pointed at the
test's), so it needs an ``nginx`` binary; ``.ci/run`` installs one.
"""

import getpass
import os
import shutil
import socket
import subprocess
import time
from pathlib import Path

import httpx
import pytest

from harness.postgres import free_port
from harness.servers import start, wait_ready

ROOT = Path(__file__).resolve().parents[1]
NGINX = shutil.which("nginx") or next((p for p in ("/usr/sbin/nginx",) if Path(p).exists()), None)
pytestmark = pytest.mark.skipif(NGINX is None, reason="needs an nginx binary (.ci/run installs it)")


def _main_config(directory: Path, api_port: int, proxy_port: int) -> Path:
    site = (ROOT / "deploy" / "nginx.conf").read_text()
    site = site.replace("server api:8000", f"server 127.0.0.1:{api_port}").replace(
        "listen 8080;", f"listen 127.0.0.1:{proxy_port};"
    )
    temp = "\n".join(
        f"    {kind}_temp_path {directory / kind};" for kind in ("client_body", "proxy", "fastcgi", "uwsgi", "scgi")
    )
    user = f"user {getpass.getuser()};\n" if os.geteuid() == 0 else ""
    config = directory / "nginx.conf"
    config.write_text(
        f"{user}daemon off;\npid {directory / 'nginx.pid'};\nerror_log {directory / 'error.log'};\n"
        f"events {{}}\nhttp {{\n    access_log off;\n{temp}\n{site}\n}}\n"
    )
    return config


@pytest.fixture(scope="module")
def proxy(tmp_path_factory):
    directory = tmp_path_factory.mktemp("proxy")
    api_port, proxy_port = free_port(), free_port()
    api = start(api_port, {"SPECTRAL_UNIONS_DATABASE_PATH": str(directory / "shapes.sqlite")})
    nginx = subprocess.Popen([NGINX, "-c", str(_main_config(directory, api_port, proxy_port))], stderr=subprocess.PIPE)
    try:
        wait_ready(f"http://127.0.0.1:{api_port}", api)
        deadline = time.monotonic() + 20
        while time.monotonic() < deadline:
            assert nginx.poll() is None, nginx.stderr.read().decode()
            try:
                if httpx.get(f"http://127.0.0.1:{proxy_port}/readyz", timeout=1).status_code == 200:
                    break
            except httpx.TransportError:
                time.sleep(0.1)
        yield proxy_port
    finally:
        nginx.terminate()
        api.kill()
        nginx.wait(timeout=20)
        api.wait(timeout=20)


def _raw(port: int, request: bytes) -> tuple[int, dict[str, str], bytes]:
    with socket.create_connection(("127.0.0.1", port), timeout=20) as connection:
        connection.sendall(request)
        data = b""
        while chunk := connection.recv(65536):
            data += chunk
            if b"\r\n\r\n" in data:
                head, _, body = data.partition(b"\r\n\r\n")
                headers = {
                    k.strip().lower(): v.strip()
                    for k, _, v in (line.partition(":") for line in head.decode().split("\r\n")[1:])
                }
                if len(body) >= int(headers.get("content-length", 0)):
                    return int(head.split()[1]), headers, body
    raise AssertionError(f"no whole response: {data!r}")


FORM = b"Content-Type: multipart/form-data; boundary=b\r\n"


@pytest.mark.parametrize(
    "request_bytes",
    [
        b"POST /v1/union HTTP/1.1\r\nHost: t\r\n" + FORM + b"Content-Length: 5\r\nTransfer-Encoding: chunked\r\n\r\n"
        b"0\r\n\r\n",
        b"POST /v1/union HTTP/1.1\r\nHost: t\r\n" + FORM + b"Content-Length: 5\r\nContent-Length: 7\r\n\r\nabcde",
        b"POST /v1/union HTTP/1.1\r\nHost: t\r\n" + FORM + b"Content-Length: 5x\r\n\r\nabcde",
        b"POST /v1/union HTTP/1.1\r\nHost: t\r\n" + FORM + b"Transfer-Encoding: chunked\r\n\r\nzz\r\nabc\r\n0\r\n\r\n",
    ],
    ids=["content-length-and-chunked", "two-content-lengths", "non-numeric-length", "bad-chunk-size"],
)
def test_malformed_framing_is_refused_by_the_proxy_as_a_problem(proxy, request_bytes):
    status, headers, body = _raw(proxy, request_bytes)
    assert status == 400, body
    assert headers["content-type"] == "application/problem+json"
    assert b'"type": "/problems/malformed-http"' in body


def test_well_formed_requests_pass_through_to_the_replica(proxy):
    response = httpx.get(f"http://127.0.0.1:{proxy}/v1/models", timeout=20)
    assert response.status_code == 200 and response.json()["k"] == 20
    problem = httpx.get(f"http://127.0.0.1:{proxy}/v1/nowhere", timeout=20)
    assert problem.status_code == 404 and problem.headers["content-type"] == "application/problem+json"
