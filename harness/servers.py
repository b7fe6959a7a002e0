"""The service as real processes on loopback ports, for the tests that need more than one."""

import os
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

from harness.postgres import free_port

STARTUP_SECONDS = 60
API_KEY = "test-key-0123456789"  # the key every test and benchmark server is started with


def start(port: int, settings: dict[str, str]) -> subprocess.Popen:
    """``spectral-unions serve`` on ``port`` with the test key, one solver worker, and ``settings``
    (environment variables, e.g. the database; they override those defaults)."""
    environment = {
        **os.environ,
        "SPECTRAL_UNIONS_API_KEY": API_KEY,
        "SPECTRAL_UNIONS_SOLVER_CONCURRENCY": "1",
        **settings,
    }
    command = [sys.executable, "-c", "from app.cli import main; main()", "serve", "--port", str(port)]
    return subprocess.Popen(command, env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)


def wait_ready(base: str, process: subprocess.Popen) -> None:
    deadline = time.monotonic() + STARTUP_SECONDS
    while time.monotonic() < deadline:
        if process.poll() is not None:
            raise RuntimeError(f"the server exited with code {process.returncode} before it was ready")
        try:
            if httpx.get(f"{base}/readyz", timeout=1).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise TimeoutError(f"{base} not ready after {STARTUP_SECONDS} s")


def serving(folder: Path, **settings: str) -> Iterator[int]:
    """A ready service (:func:`start`) with its SQLite database in ``folder`` and ``settings``;
    yields its port, and stops it after (a module fixture's body)."""
    port = free_port()
    process = start(port, {"SPECTRAL_UNIONS_DATABASE_PATH": str(folder / "shapes.sqlite"), **settings})
    try:
        wait_ready(f"http://127.0.0.1:{port}", process)
        yield port
    finally:
        process.kill()
        process.wait(timeout=30)
