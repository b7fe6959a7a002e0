"""Cheap hostile uploads against a live service: does a normal client keep its latency, and is
excess load refused before its bodies are read?

Run: ``python -m benchmarks.hostile_uploads`` from the repository root (dev extras). It starts
the service on a free port with its defaults (a solver worker per core), then runs:

1. **loop**: one normal client uploads a partial template body (~10 k vertices, ~0.4 MB)
   back to back, first alone for ``--alone`` seconds, then for ``--attacked`` seconds while
   ``--attackers`` clients send hostile files in a loop: a disk with 100 000
   copies of one face, 20 000 fins on one edge, a GLB of 30 000 instances, and an ASCII PLY
   that declares 3 vertices and carries 15 M more lines (30 MB). Printed: the normal client's
   p50 / p95 / max latency in both phases, and each hostile file's status and median time.
   ``--control`` has the other clients send the normal file instead: what the same number of
   honest clients costs the normal one.
2. **burst**: ``--burst`` concurrent uploads of the normal file on an idle server, ``--rounds``
   times, each sent as curl sends a large body (``Expect: 100-continue``: the body follows the
   server's 100 only): how many were served and how many refused (503), and the latencies.
3. **probe**: each file of an independent probe that was misread, a 500 or dear to refuse,
   sent once (counts of thousands of digits, a PLY read two ways, unbudgeted text, decimal
   commas, byte-order marks, GLB storage trimesh misreads, faces wound both ways): its status,
   problem type and time, and whether any answer was a 5xx; then a repeated form field under a
   capitalized media type, and the size warning of operands one of which has no positive
   eigenvalue (which operands it names).
4. **crowd**: a union of ``--union-files`` parts, and while its solves run a normal upload;
   then eight chunked bodies that trickle a byte at a time, and a normal upload beside them:
   what the normal uploads got, and how long they took.

Figures go in ``docs/reliability.md``.
"""

import argparse
import asyncio
import json
import os
import statistics
import tempfile
import time
from collections import defaultdict
from pathlib import Path

import httpx
import numpy as np
import trimesh
from scipy.spatial import Delaunay

from app.core.config import Settings
from app.geometry.shapes import Mesh
from app.inference.template import Template
from app.samples import template_part
from harness.builders import glb_of, instanced_glb, mesh_bytes
from harness.postgres import free_port
from harness.servers import start, wait_ready


def _disk(points: int, seed: int = 0) -> Mesh:
    xy = np.random.default_rng(seed).uniform(-1, 1, (3 * points, 2))
    xy = xy[np.hypot(*xy.T) < 1][:points]
    return Mesh(np.c_[xy, np.zeros(len(xy))], Delaunay(xy).simplices.astype(np.int64))


def hostile_files() -> dict[str, tuple[str, bytes]]:
    """Cheap hostile uploads, each under the default 64 MiB cap: name → (file name, bytes)."""
    disk = _disk(700)
    copies = Mesh(disk.vertices, np.r_[disk.faces, np.repeat(disk.faces[:1], 100_000, axis=0)])
    a, b = disk.faces[0, :2]
    apexes = (disk.vertices[a] + disk.vertices[b]) / 2 + np.random.default_rng(1).normal(0, 0.01, (20_000, 3))
    fins = np.c_[np.full(20_000, a), np.full(20_000, b), len(disk.vertices) + np.arange(20_000)]
    finned = Mesh(np.r_[disk.vertices, apexes], np.r_[disk.faces, fins])
    header = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    header += b"element face 1\nproperty list uchar int vertex_indices\nend_header\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    sphere = trimesh.creation.icosphere(subdivisions=1)
    return {
        "100k repeated faces": ("copies.ply", mesh_bytes(copies, "ply")),
        "20k fins on an edge": ("fins.ply", mesh_bytes(finned, "ply")),
        "30k-instance GLB": ("nodes.glb", instanced_glb(Mesh(sphere.vertices, sphere.faces), 30_000)),
        "3 vertices + 15M lines": ("long.ply", header + b"0\n" * 15_000_000),
    }


def probe_files(part: bytes) -> dict[str, tuple[str, bytes]]:
    """The probe's reproducers, each under the default 64 MiB cap: name → (file name, bytes)."""
    xyz_header = b"property float x\nproperty float y\nproperty float z\n"
    digits = b"9" * 5000
    patch = _disk(400)
    wound = Mesh(patch.vertices, patch.faces.copy())
    wound.faces[::2] = wound.faces[::2, ::-1]
    sphere = trimesh.creation.icosphere(subdivisions=1)
    ball = Mesh(sphere.vertices, sphere.faces)
    facet = b"facet normal 0 0 1\nouter loop\n" + b"vertex 0 0 0\n" * 3 + b"endloop\nendfacet\n"
    return {
        "PLY vertex count of 5000 digits": (
            "d.ply",
            b"ply\nformat ascii 1.0\nelement vertex " + digits + b"\n" + xyz_header + b"end_header\n",
        ),
        "OFF count of 5000 digits": ("d.off", b"OFF\n" + digits + b" 1 0\n0 0 0\n"),
        "'comment ascii' binary PLY, 10M text rows": (
            "trick.ply",
            b"ply\ncomment ascii\nformat binary_little_endian 1.0\nelement vertex 10000000\n"
            + xyz_header
            + b"end_header\n"
            + b"0 0 0\n" * 10_000_000,
        ),
        "OBJ of 7.5M v lines": ("many.obj", b"v 0 0 0\n" * 7_500_000),
        "OBJ face line of 8M indices": ("face.obj", b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + b"1 2 3 " * 2_700_000 + b"\n"),
        "XYZ line of 30M tokens": ("line.xyz", b"0 " * 30_000_000 + b"\n"),
        "XYZ 100k rows of 200 tokens": ("wide.xyz", (b"0 " * 200 + b"\n") * 100_000),
        "ASCII STL of 600k facets": ("many.stl", b"solid x\n" + facet * 600_000 + b"endsolid x\n"),
        "XYZ with decimal commas": (
            "comma.xyz",
            b"".join(b"0,%d 0,%d 0,%d\n" % (i, i + 1, i + 2) for i in range(1000)),
        ),
        "XYZ of 3 then 4 columns": ("cols.xyz", b"0 0 0\n" + b"".join(b"%d 1 0 1\n" % i for i in range(1000))),
        "OBJ with a byte-order mark": ("bom.obj", b"\xef\xbb\xbf" + mesh_bytes(patch, "obj")),
        "GLB with a sparse accessor": (
            "sparse.glb",
            glb_of(
                ball,
                sparse={"count": 1, "indices": {"bufferView": 1, "componentType": 5125}, "values": {"bufferView": 0}},
            ),
        ),
        "GLB with quantized positions": ("quantized.glb", glb_of(ball, componentType=5122, normalized=True)),
        "a hole in faces wound both ways, cap_holes": ("wound.ply", mesh_bytes(wound, "ply")),
        "the normal part": ("part.ply", part),
    }


async def probe_scenario(url: str, part: bytes) -> dict:
    rows = {}
    async with httpx.AsyncClient(timeout=300) as http:
        for label, (name, data) in probe_files(part).items():
            params = {"cap_holes": "true"} if "cap_holes" in label else {}
            started = time.perf_counter()
            response = await http.post(f"{url}/v1/spectrum", params=params, files={"file": (name, data)})
            elapsed = time.perf_counter() - started
            answer = response.json()
            rows[label] = {
                "bytes": len(data),
                "status": response.status_code,
                "type": answer.get("type", ""),
                "ms": round(1e3 * elapsed, 1),
                "holes_filled": answer.get("holes_filled"),
            }
        rows.update(await _probe_forms(http, url))
    return {"files": rows, "server_errors": sum(row["status"] >= 500 for row in rows.values())}


async def _probe_forms(http: httpx.AsyncClient, url: str) -> dict[str, dict]:
    """The probe's form reproducers: a repeated field under a capitalized media type, and the
    size warning of operands one of which has no positive eigenvalue."""
    spectrum = np.linspace(1.0, 20.0, 20)
    field = b'--b\r\nContent-Disposition: form-data; name="spectra"\r\n\r\n[[1, 2]]\r\n'
    repeated = await http.post(
        f"{url}/v1/union", content=field * 2 + b"--b--\r\n", headers={"content-type": "Multipart/Form-Data; boundary=b"}
    )
    spectra = json.dumps([np.zeros(20).tolist(), spectrum.tolist(), (1e4 * spectrum).tolist()])
    warned = await http.post(f"{url}/v1/union", data={"spectra": spectra})
    return {
        "two spectra fields, 'Multipart/Form-Data'": {
            "status": repeated.status_code,
            "type": repeated.json().get("type", ""),
        },
        "size warning of [zeros, A, A of a body 100x smaller]": {
            "status": warned.status_code,
            "warning": (warned.json().get("warnings") or [""])[0][:40],
        },
    }


async def _trickle(port: int, stop: asyncio.Event) -> None:
    """A chunked upload that sends one byte every second until ``stop``."""
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    writer.write(
        b"POST /v1/spectrum HTTP/1.1\r\nHost: x\r\nContent-Type: multipart/form-data; boundary=b\r\n"
        b"Transfer-Encoding: chunked\r\n\r\n"
    )
    try:
        while not stop.is_set():
            writer.write(b"1\r\n-\r\n")
            await writer.drain()
            await asyncio.sleep(1.0)
    except OSError:
        pass
    finally:
        writer.close()


async def _timed_upload(http: httpx.AsyncClient, url: str, part: bytes) -> dict:
    started = time.perf_counter()
    response = await http.post(f"{url}/v1/spectrum", files={"file": ("part.ply", part)})
    return {"status": response.status_code, "ms": round(1e3 * (time.perf_counter() - started), 1)}


async def crowd_scenario(url: str, port: int, part: bytes, union_files: int) -> dict:
    async with httpx.AsyncClient(timeout=300) as http:
        files = [("files", (f"p{i}.ply", part)) for i in range(union_files)]
        union = asyncio.create_task(http.post(f"{url}/v1/union", files=files))
        await asyncio.sleep(1.0)  # its form read, its solves under way
        beside_union = await _timed_upload(http, url, part)
        union_status = (await union).status_code
        stop = asyncio.Event()
        trickles = [asyncio.create_task(_trickle(port, stop)) for _ in range(8)]
        await asyncio.sleep(2.0)
        beside_trickles = await _timed_upload(http, url, part)
        stop.set()
        await asyncio.gather(*trickles)
    return {
        "union_status": union_status,
        "upload_beside_the_union": beside_union,
        "upload_beside_8_trickling_bodies": beside_trickles,
    }


def _quantiles(values: list[float]) -> dict[str, float | None]:
    if not values:
        return {"p50_ms": None, "p95_ms": None, "max_ms": None}
    ordered = sorted(values)
    return {
        "p50_ms": round(1e3 * statistics.median(ordered), 1),
        "p95_ms": round(1e3 * ordered[min(len(ordered) - 1, int(0.95 * len(ordered)))], 1),
        "max_ms": round(1e3 * ordered[-1], 1),
    }


async def _normal_client(url: str, body: bytes, seconds: float) -> dict:
    latencies, failures = [], defaultdict(int)
    async with httpx.AsyncClient(timeout=300) as http:
        stop = time.monotonic() + seconds
        while time.monotonic() < stop:
            started = time.perf_counter()
            response = await http.post(f"{url}/v1/spectrum", files={"file": ("part.ply", body)})
            if response.status_code == 200:
                latencies.append(time.perf_counter() - started)
            else:
                failures[response.status_code] += 1
    return {"served": len(latencies), **_quantiles(latencies), "not_served": dict(failures)}


async def _attacker(url: str, files: dict[str, tuple[str, bytes]], stop: asyncio.Event, seen: dict) -> None:
    async with httpx.AsyncClient(timeout=300) as http:
        while not stop.is_set():
            for label, (name, data) in files.items():
                if stop.is_set():
                    return
                started = time.perf_counter()
                try:
                    response = await http.post(f"{url}/v1/spectrum", files={"file": (name, data)})
                    outcome = f"{response.status_code} {response.json().get('type', '')}"
                except httpx.HTTPError as exc:
                    outcome = type(exc).__name__
                seen[label].append((outcome, time.perf_counter() - started))


async def loop_scenario(url: str, body: bytes, args: argparse.Namespace) -> dict:
    alone = await _normal_client(url, body, args.alone)
    files = {"normal upload": ("part.ply", body)} if args.control else hostile_files()
    stop, seen = asyncio.Event(), defaultdict(list)
    attackers = [asyncio.create_task(_attacker(url, files, stop, seen)) for _ in range(args.attackers)]
    await asyncio.sleep(1.0)  # the attack is under way before the normal client measures
    attacked = await _normal_client(url, body, args.attacked)
    stop.set()
    await asyncio.wait(attackers, timeout=300)
    hostile = {
        label: {
            "sent": len(results),
            "outcomes": sorted({outcome for outcome, _ in results}),
            "median_ms": round(1e3 * statistics.median(t for _, t in results), 1) if results else None,
        }
        for label, results in seen.items()
    }
    return {"alone": alone, "attacked": attacked, "hostile": hostile}


async def _expecting_upload(port: int, body: bytes) -> tuple[int, float]:
    """One multipart upload as curl sends a large body: headers with ``Expect: 100-continue``,
    the body only after the server's 100. Returns the final status and the seconds it took."""
    boundary = "burst"
    part = (
        (
            f'--{boundary}\r\nContent-Disposition: form-data; name="file"; filename="part.ply"\r\n'
            "Content-Type: application/octet-stream\r\n\r\n"
        ).encode()
        + body
        + f"\r\n--{boundary}--\r\n".encode()
    )
    head = (
        f"POST /v1/spectrum HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nExpect: 100-continue\r\n"
        f"Content-Type: multipart/form-data; boundary={boundary}\r\nContent-Length: {len(part)}\r\n\r\n"
    ).encode()
    started = time.perf_counter()
    reader, writer = await asyncio.open_connection("127.0.0.1", port)
    try:
        writer.write(head)
        await writer.drain()
        status = int((await reader.readuntil(b"\r\n\r\n")).split()[1])
        if status == 100:
            writer.write(part)
            await writer.drain()
            status = int((await reader.readuntil(b"\r\n\r\n")).split()[1])
        return status, time.perf_counter() - started
    except (OSError, asyncio.IncompleteReadError):
        return -1, time.perf_counter() - started
    finally:
        writer.close()


async def burst_scenario(port: int, body: bytes, concurrent: int) -> dict:
    results = await asyncio.gather(*(_expecting_upload(port, body) for _ in range(concurrent)))
    refused = [t for status, t in results if status == 503]
    served = [t for status, t in results if status == 200]
    return {
        "served": len(served),
        "served_latency": _quantiles(served),
        "refused_503": len(refused),
        "refused_latency": _quantiles(refused),
        "other": sorted(status for status, _ in results if status not in (200, 503)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--alone", type=float, default=30.0, help="seconds of the normal client alone")
    parser.add_argument("--attacked", type=float, default=60.0, help="seconds of the normal client under attack")
    parser.add_argument("--attackers", type=int, default=2, help="clients sending the hostile files")
    parser.add_argument("--burst", type=int, default=64, help="concurrent uploads of the burst")
    parser.add_argument("--rounds", type=int, default=3, help="bursts, each on an idle server")
    parser.add_argument("--union-files", type=int, default=32, help="crowd: files in the union")
    parser.add_argument("--only", choices=["loop", "burst", "probe", "crowd"], help="run one scenario only")
    parser.add_argument(
        "--control", action="store_true", help="loop: the other clients send the normal file instead (the baseline)"
    )
    args = parser.parse_args()

    body = template_part(Template.load(Settings().models_dir), ("head", "neck"))
    port = free_port()
    url = f"http://127.0.0.1:{port}"
    report: dict = {"cores": os.cpu_count(), "normal_upload_bytes": len(body)}
    with tempfile.TemporaryDirectory() as folder:
        server = start(
            port,
            {
                "SPECTRAL_UNIONS_DATABASE_PATH": str(Path(folder) / "shapes.sqlite"),
                "SPECTRAL_UNIONS_SOLVER_CONCURRENCY": str(os.cpu_count() or 1),
            },
        )
        try:
            wait_ready(url, server)
            if args.only in (None, "burst"):
                rounds = []
                for _ in range(args.rounds):
                    rounds.append(asyncio.run(burst_scenario(port, body, args.burst)))
                    time.sleep(2.0)  # idle again before the next burst
                report["burst"] = rounds
            if args.only in (None, "loop"):
                report["loop"] = asyncio.run(loop_scenario(url, body, args))
            if args.only in (None, "probe"):
                report["probe"] = asyncio.run(probe_scenario(url, body))
            if args.only in (None, "crowd"):
                report["crowd"] = asyncio.run(crowd_scenario(url, port, body, args.union_files))
        finally:
            server.terminate()
            server.wait(timeout=60)
    print(json.dumps(report, indent=1))


if __name__ == "__main__":
    main()
