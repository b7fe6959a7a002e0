"""Overload of ``/v1/union`` on loopback: saturation, 0.8·X held, 2·X pushed, recovery.

Run: ``python -m benchmarks.overload`` from the repository root (dev extras). It starts the service on a free port with
its defaults (a solver worker per core, 16 queued solves), then:

1. **saturation**: closed loop, enough clients to keep every solver busy, for ``--probe``
   seconds; X = successful unions per second;
2. **hold**: open loop (requests sent on a fixed schedule, whatever the answers) at 0.8·X for
   ``--hold`` seconds: p50/p99 latency and error rate;
3. **push**: open loop at 2·X for ``--push`` seconds: the excess must be shed as 503 with
   ``Retry-After`` in milliseconds, the admitted rest served, memory flat;
4. **recover**: open loop at 0.5·X for ``--recover`` seconds: no errors, latency back.

Each request uploads two partial scans of the template body (~10 k vertices each), so it
parses, assembles and solves twice and runs the operator. The server's resident memory
(its process tree) is sampled every second. Figures go in ``docs/reliability.md``.
"""

import argparse
import asyncio
import json
import os
import tempfile
import time
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np

from app.core.config import Settings
from app.inference.template import Template
from app.samples import PARTS, template_part
from harness.postgres import free_port
from harness.servers import start, wait_ready


def tree_rss_mb(pid: int) -> float:
    """Resident memory of a process and all its descendants (the solver workers), from /proc."""
    total, pending = 0.0, [pid]
    while pending:
        current = pending.pop()
        try:
            status = Path(f"/proc/{current}/status").read_text()
            children = Path(f"/proc/{current}/task/{current}/children").read_text().split()
        except OSError:
            continue
        # A retired worker not yet reaped is a zombie: it has no VmRSS line and no memory.
        total += sum(int(line.split()[1]) for line in status.splitlines() if line.startswith("VmRSS:")) / 1024
        pending += [int(child) for child in children]
    return total


@dataclass
class Phase:
    name: str
    offered_rps: float
    seconds: float
    ok: list[float] = field(default_factory=list)  # latencies of 200s
    shed: list[float] = field(default_factory=list)  # latencies of 503 overloaded
    errors: dict[str, int] = field(default_factory=dict)
    retry_after: set[str] = field(default_factory=set)
    rss_mb: list[float] = field(default_factory=list)

    def row(self) -> dict:
        sent = len(self.ok) + len(self.shed) + sum(self.errors.values())

        def quantiles(values: list[float]) -> list[float | None]:
            if not values:
                return [None, None]
            return [round(float(q), 1) for q in np.percentile(np.array(values) * 1e3, [50, 99])]

        return {
            "phase": self.name,
            "offered_rps": round(self.offered_rps, 2),
            "sent": sent,
            "ok_rps": round(len(self.ok) / self.seconds, 2),
            "ok_p50_p99_ms": quantiles(self.ok),
            "shed": len(self.shed),
            "shed_fraction": round(len(self.shed) / sent, 3) if sent else None,
            "shed_p50_p99_ms": quantiles(self.shed),
            "retry_after": sorted(self.retry_after),
            "other_errors": self.errors,
            "rss_mb_first_max_last": [
                round(min(self.rss_mb[:1] or [0]), 1),
                round(max(self.rss_mb or [0]), 1),
                round((self.rss_mb or [0])[-1], 1),
            ],
        }


async def one_request(http: httpx.AsyncClient, url: str, files: list, phase: Phase) -> None:
    started = time.perf_counter()
    try:
        response = await http.post(f"{url}/v1/union", files=files)
    except httpx.HTTPError as exc:
        phase.errors[type(exc).__name__] = phase.errors.get(type(exc).__name__, 0) + 1
        return
    elapsed = time.perf_counter() - started
    if response.status_code == 200:
        phase.ok.append(elapsed)
    elif response.status_code == 503 and response.json().get("type") == "/problems/overloaded":
        phase.shed.append(elapsed)
        phase.retry_after.add(response.headers.get("retry-after", "missing"))
    else:
        key = str(response.status_code)
        phase.errors[key] = phase.errors.get(key, 0) + 1


async def sample_memory(pid: int, phase: Phase, stop: asyncio.Event) -> None:
    while not stop.is_set():
        phase.rss_mb.append(tree_rss_mb(pid))
        await asyncio.sleep(1.0)


async def closed_loop(url: str, files: list, clients: int, phase: Phase, pid: int) -> None:
    deadline = time.perf_counter() + phase.seconds

    async def client(http: httpx.AsyncClient) -> None:
        while time.perf_counter() < deadline:
            await one_request(http, url, files, phase)

    stop = asyncio.Event()
    sampler = asyncio.create_task(sample_memory(pid, phase, stop))
    async with httpx.AsyncClient(timeout=120, limits=httpx.Limits(max_connections=clients)) as http:
        await asyncio.gather(*(client(http) for _ in range(clients)))
    stop.set()
    await sampler


async def open_loop(url: str, files: list, phase: Phase, pid: int) -> None:
    """Requests leave every 1/rate seconds whether or not earlier ones were answered."""
    stop = asyncio.Event()
    sampler = asyncio.create_task(sample_memory(pid, phase, stop))
    interval = 1.0 / phase.offered_rps
    tasks = []
    async with httpx.AsyncClient(timeout=120, limits=httpx.Limits(max_connections=None)) as http:
        started = time.perf_counter()
        for index in range(int(phase.seconds * phase.offered_rps)):
            await asyncio.sleep(max(0.0, started + index * interval - time.perf_counter()))
            tasks.append(asyncio.create_task(one_request(http, url, files, phase)))
        await asyncio.gather(*tasks)
    stop.set()
    await sampler


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--probe", type=float, default=30.0, help="seconds of the saturation probe")
    parser.add_argument("--hold", type=float, default=180.0, help="seconds at 0.8·X")
    parser.add_argument("--push", type=float, default=60.0, help="seconds at 2·X")
    parser.add_argument("--recover", type=float, default=30.0, help="seconds at 0.5·X")
    args = parser.parse_args()

    template = Template.load(Settings().models_dir)
    parts = [template_part(template, removed) for removed in PARTS.values()]
    files = [("files", (f"part{i}.ply", data, "application/octet-stream")) for i, data in enumerate(parts)]
    solvers = os.cpu_count() or 1
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    with tempfile.TemporaryDirectory() as folder:
        server = start(
            port,
            {
                "SPECTRAL_UNIONS_DATABASE_PATH": str(Path(folder) / "shapes.sqlite"),
                "SPECTRAL_UNIONS_SOLVER_CONCURRENCY": str(solvers),
            },
        )
        try:
            wait_ready(url, server)
            saturation = Phase("saturation (closed loop)", float("nan"), args.probe)
            asyncio.run(closed_loop(url, files, 2 * solvers + 2, saturation, server.pid))
            capacity = len(saturation.ok) / args.probe
            phases = [saturation]
            for name, factor, seconds in (
                ("hold 0.8·X", 0.8, args.hold),
                ("push 2·X", 2.0, args.push),
                ("recover 0.5·X", 0.5, args.recover),
            ):
                phase = Phase(name, factor * capacity, seconds)
                asyncio.run(open_loop(url, files, phase, server.pid))
                phases.append(phase)
        finally:
            server.terminate()
            server.wait(timeout=60)
    print(json.dumps({"cores": os.cpu_count(), "solver_workers": solvers, "saturation_rps": round(capacity, 2)}))
    for phase in phases:
        print(json.dumps(phase.row()))


if __name__ == "__main__":
    main()
