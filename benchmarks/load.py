"""Load on ``/v1/union`` over loopback, and where one request's time goes.

Run: ``python benchmarks/load.py`` (the dev extras; no anny, no torch). It starts the service
on a free loopback port with its embedded defaults (or uses ``--url``), then drives it with an
async httpx client at a fixed concurrency for a fixed time, in two scenarios:

- ``files``: two uploaded PLY parts of the template body (each ~10 k vertices), so every
  request parses, assembles two Laplacians, solves two eigenproblems and runs the operator;
- ``spectra``: the same two parts sent as the spectra the first scenario returned, so only
  validation and the operator run.

Then, one client at a time (``--latency-seconds`` each), the latency of ``/v1/spectrum`` of each
part alone and of ``/v1/union`` of the two uploads: the union's p50 over the sum of the two
spectra's p50 says whether a request's uploads are solved side by side (0.5 on two free cores)
or one after the other (1.0). It prints p50/p95/p99 latency, throughput and error counts per
scenario, then an in-process single-request breakdown (parse and checks, Laplacian assembly, eigen-solve, inference;
median of repeats). Figures go in the README's performance section.
"""

import argparse
import asyncio
import json
import os
import statistics
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import httpx
import numpy as np
import trimesh

from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions, spectrum_from_bytes
from app.inference.models import SpectralModels
from app.inference.template import Template
from app.samples import PARTS, template_part


@dataclass
class Tally:
    latencies: list[float]
    errors: dict[str, int]
    seconds: float

    def summary(self, name: str) -> dict:
        ms = np.array(self.latencies) * 1e3
        quantiles = np.percentile(ms, [50, 95, 99]) if len(ms) else [float("nan")] * 3
        return {
            "scenario": name,
            "requests": len(ms) + sum(self.errors.values()),
            "ok": len(ms),
            "errors": self.errors,
            "throughput_rps": round(len(ms) / self.seconds, 2),
            "p50_ms": round(float(quantiles[0]), 1),
            "p95_ms": round(float(quantiles[1]), 1),
            "p99_ms": round(float(quantiles[2]), 1),
        }


async def drive(url: str, request: dict, concurrency: int, seconds: float, endpoint: str = "/v1/union") -> Tally:
    """``concurrency`` clients posting ``request`` to ``endpoint`` back to back for ``seconds``."""
    tally = Tally([], {}, seconds)
    deadline = time.perf_counter() + seconds

    async def client(http: httpx.AsyncClient) -> None:
        while time.perf_counter() < deadline:
            started = time.perf_counter()
            try:
                response = await http.post(f"{url}{endpoint}", **request)
                if response.status_code == 200:
                    tally.latencies.append(time.perf_counter() - started)
                    continue
                key = str(response.status_code)
            except httpx.HTTPError as exc:
                key = type(exc).__name__
            tally.errors[key] = tally.errors.get(key, 0) + 1

    limits = httpx.Limits(max_connections=concurrency)
    async with httpx.AsyncClient(timeout=120, limits=limits) as http:
        await asyncio.gather(*(client(http) for _ in range(concurrency)))
    return tally


def breakdown(parts: list[bytes], models: SpectralModels, repeats: int) -> dict[str, float]:
    """Median milliseconds of each stage of one two-part union, in process."""
    stages: dict[str, list[float]] = {"parse_and_checks": [], "laplacian": [], "eigensolve": [], "inference": []}
    options = SpectrumOptions()
    for _ in range(repeats):
        spectra, times = [], dict.fromkeys(stages, 0.0)
        for data in parts:
            started = time.perf_counter()
            report = spectrum_from_bytes(data, "ply", options)
            total = (time.perf_counter() - started) * 1e3
            times["parse_and_checks"] += total - report.assembly_ms - report.solve_ms
            times["laplacian"] += report.assembly_ms
            times["eigensolve"] += report.solve_ms
            spectra.append(np.asarray(report.eigenvalues))
        started = time.perf_counter()
        models.union(spectra)
        times["inference"] = (time.perf_counter() - started) * 1e3
        for name, value in times.items():
            stages[name].append(value)
    return {name: round(statistics.median(values), 2) for name, values in stages.items()}


def start_server(port: int) -> subprocess.Popen:
    command = [sys.executable, "-c", "from app.cli import main; main()", "serve", "--port", str(port)]
    environment = {**os.environ, "SPECTRAL_UNIONS_DATABASE_PATH": str(Path.cwd() / "bench-load.sqlite")}
    server = subprocess.Popen(command, env=environment, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    for _ in range(300):
        try:
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=1).status_code == 200:
                return server
        except httpx.TransportError:
            time.sleep(0.2)
    server.kill()
    raise RuntimeError("the service did not become ready")


def stop_server(server: subprocess.Popen) -> None:
    """Stop a server of :func:`start_server` and remove its database."""
    server.terminate()
    server.wait(timeout=30)
    for suffix in ("", "-wal", "-shm"):
        Path(f"bench-load.sqlite{suffix}").unlink(missing_ok=True)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--url", help="an already running service (default: start one)")
    parser.add_argument("--port", type=int, default=8765)
    parser.add_argument("--seconds", type=float, default=30.0, help="per scenario")
    parser.add_argument("--concurrency", type=int, default=8)
    parser.add_argument("--repeats", type=int, default=7, help="for the single-request breakdown")
    parser.add_argument("--latency-seconds", type=float, default=15.0, help="per one-client latency scenario")
    args = parser.parse_args()

    settings = Settings()
    template = Template.load(settings.models_dir)
    parts = [template_part(template, removed) for removed in PARTS.values()]
    sizes = [len(trimesh.load(trimesh.util.wrap_as_stream(p), file_type="ply").vertices) for p in parts]
    server = None if args.url else start_server(args.port)
    url = args.url or f"http://127.0.0.1:{args.port}"
    try:
        files = [("files", (f"part{i}.ply", data, "application/octet-stream")) for i, data in enumerate(parts)]
        first = httpx.post(f"{url}/v1/union", files=files, timeout=120).json()
        spectra = json.dumps([operand["eigenvalues"] for operand in first["operands"]])
        results = [
            asyncio.run(drive(url, {"files": files}, args.concurrency, args.seconds)).summary("files"),
            asyncio.run(drive(url, {"data": {"spectra": spectra}}, args.concurrency, args.seconds)).summary("spectra"),
        ]
        alone = [
            asyncio.run(drive(url, {"files": {"file": file[1]}}, 1, args.latency_seconds, "/v1/spectrum"))
            for file in files
        ]
        together = asyncio.run(drive(url, {"files": files}, 1, args.latency_seconds))
        latency = [tally.summary(f"/v1/spectrum, part {i} alone") for i, tally in enumerate(alone)]
        latency.append(together.summary("/v1/union, both uploaded"))
    finally:
        if server:
            stop_server(server)
    models = SpectralModels(settings.models_dir)
    print(json.dumps({"cores": os.cpu_count(), "part_vertices": sizes, "concurrency": args.concurrency}, indent=1))
    print("| scenario | requests | ok | errors | throughput (req/s) | p50 ms | p95 ms | p99 ms |")
    print("|---|---|---|---|---|---|---|---|")
    for r in results:
        print(
            f"| {r['scenario']} | {r['requests']} | {r['ok']} | {r['errors'] or 0} | {r['throughput_rps']} | "
            f"{r['p50_ms']} | {r['p95_ms']} | {r['p99_ms']} |"
        )
    print("\none client at a time:")
    print("| request | requests | p50 ms | p95 ms |")
    print("|---|---|---|---|")
    for r in latency:
        print(f"| {r['scenario']} | {r['ok']} | {r['p50_ms']} | {r['p95_ms']} |")
    ratio = latency[-1]["p50_ms"] / (latency[0]["p50_ms"] + latency[1]["p50_ms"])
    print(f"union p50 / sum of the two spectrum p50s: {ratio:.2f}")
    print("\nsingle two-part union, in process (median ms per request):")
    print(json.dumps(breakdown(parts, models, args.repeats), indent=1))


if __name__ == "__main__":
    main()
