"""The service as real processes on loopback ports, for the tests that need more than one."""

import os
import subprocess
import sys
import time

import httpx

from tests.api.conftest import API_KEY

STARTUP_SECONDS = 60


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
