"""Fault runs against a live service: what was broken, what clients saw, how it came back.

Run: ``python -m benchmarks.faults`` from the repository root (dev extras; the database fault
needs the PostgreSQL server binaries, the full-disk fault needs root to mount a small tmpfs;
each is reported as skipped otherwise). Scenarios, each on a fresh server:

- ``worker-kill``: SIGKILL the solver workers in the middle of a solve;
- ``database-stop``: stop PostgreSQL under a running service, then start it again;
- ``model-corrupt``: start a replica whose ``union.onnx`` has one flipped byte;
- ``spool-full``: fill the upload temporary space, upload, then free it.

Each prints one JSON line per step: what it did and what it saw (status, problem slug, time).
Figures go in ``docs/reliability.md``.
"""

import argparse
import json
import os
import shutil
import signal
import subprocess
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import trimesh

from app.core.config import Settings
from app.inference.template import Template
from app.samples import template_part
from harness.postgres import ThrowawayPostgres, free_port
from harness.servers import start, wait_ready

TEMPLATE = Template.load(Settings().models_dir)
PART = template_part(TEMPLATE, ("head", "neck"))


def report(scenario: str, did: str, response: httpx.Response | None = None, **seen) -> None:
    if response is not None:
        seen["status"] = response.status_code
        if response.headers.get("content-type") == "application/problem+json":
            seen["problem"] = response.json()["type"].removeprefix("/problems/")
            seen["detail"] = response.json()["detail"][:120]
        if "retry-after" in response.headers:
            seen["retry_after"] = response.headers["retry-after"]
        seen["ms"] = round(response.elapsed.total_seconds() * 1e3, 1)
    print(json.dumps({"scenario": scenario, "did": did, "saw": seen}), flush=True)


@contextmanager
def service(settings: dict[str, str]) -> Iterator[tuple[str, subprocess.Popen]]:
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    process = start(port, settings)
    try:
        yield base, process
    finally:
        process.terminate()
        process.wait(timeout=60)


def upload(base: str, data: bytes = PART, **params) -> httpx.Response:
    return httpx.post(f"{base}/v1/spectrum", files={"file": ("part.ply", data)}, params=params, timeout=120)


def until(predicate: Callable[[], bool], seconds: float = 60.0) -> float:
    """Seconds until ``predicate`` holds (polled every 50 ms); inf if it never does."""
    started = time.monotonic()
    while time.monotonic() - started < seconds:
        if predicate():
            return round(time.monotonic() - started, 2)
        time.sleep(0.05)
    return float("inf")


def grandchildren(pid: int) -> list[int]:
    """Solver workers: children of the fork server, itself a child of the service."""

    def children(of: int) -> list[int]:
        listing = subprocess.run(["pgrep", "-P", str(of)], capture_output=True, text=True).stdout
        return [int(line) for line in listing.split()]

    return [worker for child in children(pid) for worker in children(child)]


def worker_kill(folder: Path) -> None:
    name = "worker-kill"
    with service({"SPECTRAL_UNIONS_DATABASE_PATH": str(folder / "db.sqlite")}) as (base, process):
        wait_ready(base, process)
        answers: list[httpx.Response] = []
        client = threading.Thread(target=lambda: answers.append(upload(base, k=200)))
        client.start()
        time.sleep(0.8)
        victims = grandchildren(process.pid)
        for pid in victims:
            os.kill(pid, signal.SIGKILL)
        client.join()
        report(name, f"SIGKILL {len(victims)} solver worker(s) 0.8 s into a k=200 solve", answers[0])
        back = until(lambda: upload(base).status_code == 200)
        replaced = set(grandchildren(process.pid)).isdisjoint(victims)
        report(name, "uploaded again until a 200", seconds_to_first_200=back, workers_replaced=replaced)


def database_stop(folder: Path) -> None:
    name = "database-stop"
    try:
        database = ThrowawayPostgres()
    except FileNotFoundError as exc:
        report(name, "skipped", reason=str(exc))
        return
    database.start()
    try:
        with service({"SPECTRAL_UNIONS_DATABASE_URL": database.url}) as (base, process):
            wait_ready(base, process)
            query = {"spectra": json.dumps([upload(base).json()["eigenvalues"]])}
            database.stop()
            report(name, "stopped PostgreSQL; GET /readyz", httpx.get(f"{base}/readyz", timeout=30))
            report(name, "POST /v1/retrieve", httpx.post(f"{base}/v1/retrieve", data=query, timeout=30))
            report(name, "POST /v1/spectrum (needs no database)", upload(base))
            report(name, "POST /v1/union (needs no database)", httpx.post(f"{base}/v1/union", data=query, timeout=30))
            database.start()
            back = until(lambda: httpx.get(f"{base}/readyz", timeout=30).status_code == 200)
            report(name, "started PostgreSQL again; polled /readyz", seconds_to_ready=back)
            report(name, "POST /v1/retrieve", httpx.post(f"{base}/v1/retrieve", data=query, timeout=30))
    finally:
        database.remove()


def model_corrupt(folder: Path) -> None:
    name = "model-corrupt"
    models = folder / "models"
    shutil.copytree(Settings().models_dir, models)
    target = models / "union.onnx"
    data = bytearray(target.read_bytes())
    data[len(data) // 2] ^= 0xFF
    target.write_bytes(bytes(data))
    settings = {"SPECTRAL_UNIONS_MODELS_DIR": str(models), "SPECTRAL_UNIONS_DATABASE_PATH": str(folder / "m.sqlite")}
    with service(settings) as (base, process):
        became = until(lambda: _answers(f"{base}/healthz"))
        report(name, "flipped one byte of union.onnx, started a replica; GET /readyz", httpx.get(f"{base}/readyz"))
        report(name, "process up (GET /healthz)", httpx.get(f"{base}/healthz"), seconds_to_live=became)
        spectra = {"spectra": json.dumps([upload(base).json()["eigenvalues"]] * 2)}
        report(name, "POST /v1/union", httpx.post(f"{base}/v1/union", data=spectra, timeout=30))
        report(name, "POST /v1/spectrum (needs no model)", upload(base))


def _answers(url: str) -> bool:
    try:
        return httpx.get(url, timeout=1).status_code == 200
    except httpx.TransportError:
        return False


def spool_full(folder: Path) -> None:
    name = "spool-full"
    spool = folder / "spool"
    spool.mkdir()
    mounted = subprocess.run(["mount", "-t", "tmpfs", "-o", "size=4m", "tmpfs", str(spool)], capture_output=True)
    if mounted.returncode != 0:
        report(name, "skipped", reason=mounted.stderr.decode().strip() or "mount failed (needs root)")
        return
    try:
        with service({"TMPDIR": str(spool), "SPECTRAL_UNIONS_DATABASE_PATH": str(folder / "s.sqlite")}) as (
            base,
            process,
        ):
            wait_ready(base, process)
            filler = spool / "filler"
            with open(filler, "wb", buffering=0) as sink:
                try:
                    while True:
                        sink.write(b"\0" * 65536)
                except OSError:
                    pass
            big = _subdivided_body()  # past Starlette's 1 MiB in-memory spool: it must go to disk
            report(name, f"filled the 4 MB spool; uploaded {len(big) / 1e6:.1f} MB", upload(base, big))
            report(name, f"meanwhile a {len(PART) / 1e6:.1f} MB upload (spooled in memory)", upload(base))
            filler.unlink()
            report(name, "freed the spool; uploaded again", upload(base, big))
    finally:
        subprocess.run(["umount", str(spool)], capture_output=True)


def _subdivided_body() -> bytes:
    vertices, faces = trimesh.remesh.subdivide(TEMPLATE.vertices, TEMPLATE.faces)
    return trimesh.Trimesh(vertices, faces, process=False).export(file_type="ply")


SCENARIOS = {
    "worker-kill": worker_kill,
    "database-stop": database_stop,
    "model-corrupt": model_corrupt,
    "spool-full": spool_full,
}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("scenarios", nargs="*", help=f"some of {', '.join(SCENARIOS)} (default: all)")
    args = parser.parse_args()
    unknown = set(args.scenarios) - set(SCENARIOS)
    if unknown:
        parser.error(f"unknown scenarios: {', '.join(sorted(unknown))}")
    for scenario in args.scenarios or SCENARIOS:
        with tempfile.TemporaryDirectory() as folder:
            SCENARIOS[scenario](Path(folder))


if __name__ == "__main__":
    main()
