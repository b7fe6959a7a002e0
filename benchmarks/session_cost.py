"""What adding a view to a scanning session costs over HTTP, beside placing that view alone.

    python -m benchmarks.session_cost [--views 10] [--repeats 5]

A live service (``spectral-unions serve``, its own SQLite file, the solver workers the machine's
cores) and one unseen anny person's session (:mod:`training.sessions.scans`, meshes in the
body's frame). For registered and unregistered sessions: ``--views`` views are added, then each
further view is timed as ``POST /v1/sessions/{id}/views`` (the view solved, placed, stored, every
view read back and the union of all of them solved or folded) against ``POST
/v1/correspondence`` of the same view (solved and placed: what every view costs at least).
Medians over ``--repeats`` views. Needs the ``train`` extra (anny).
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import httpx
import trimesh

from harness.postgres import free_port
from harness.servers import start, wait_ready
from training.sessions.scans import people, view_meshes


def ply(mesh) -> bytes:
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type="ply")


def timed_post(client: httpx.Client, url: str, scan: bytes) -> float:
    """Milliseconds of one upload to ``url``."""
    started = time.perf_counter()
    client.post(url, files={"file": ("view.ply", scan)}).raise_for_status()
    return (time.perf_counter() - started) * 1e3


def measure(base: str, scans: list[bytes], views: int, repeats: int, registered: bool) -> tuple[float, float]:
    """Median ms of adding view ``views + 1`` (of a session holding ``views``) and of placing it alone."""
    added, placed = [], []
    with httpx.Client(base_url=base, timeout=300) as client:
        for repeat in range(repeats):
            session = client.post("/v1/sessions", json={"registered": registered}).json()["id"]
            for index in range(views):
                client.post(f"/v1/sessions/{session}/views", files={"file": (f"v{index}.ply", scans[index])})
            extra = scans[views + repeat % (len(scans) - views)]
            placed.append(timed_post(client, "/v1/correspondence", extra))
            added.append(timed_post(client, f"/v1/sessions/{session}/views", extra))
            client.delete(f"/v1/sessions/{session}")
    return statistics.median(added), statistics.median(placed)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--views", type=int, default=10)
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--seed", type=int, default=7)
    args = parser.parse_args()
    sampler, (person,) = people(1, args.seed)
    scans = [ply(mesh) for mesh in view_meshes(person, sampler.template.faces, "mesh")]
    if len(scans) <= args.views:
        raise SystemExit(f"the session has {len(scans)} views: ask for fewer than that")
    with tempfile.TemporaryDirectory() as folder:
        port = free_port()
        process = start(port, {"SPECTRAL_UNIONS_DATABASE_PATH": str(Path(folder) / "cost.sqlite")})
        try:
            base = f"http://127.0.0.1:{port}"
            wait_ready(base, process)
            print(f"| session | view {args.views + 1} added | the view placed alone | ratio |")
            print("|---|---|---|---|")
            for registered in (True, False):
                added, placed = measure(base, scans, args.views, args.repeats, registered)
                kind = "registered (fused)" if registered else "unregistered (aligned)"
                print(f"| {kind} | {added:.0f} ms | {placed:.0f} ms | {added / placed:.2f}× |")
        finally:
            process.terminate()
            process.wait(timeout=30)


if __name__ == "__main__":
    main()
