"""What a solver worker holds between tasks: its resident memory after each of a run of uploads.

    python -m benchmarks.worker_memory [--points 99000]

Runs the worker's own task (:func:`app.api.solver._solve_task`: solve, then place with the
served correspondence graph) in this process, one upload after another as one worker meets
them: the template body as a 12 k-vertex mesh, three closed point clouds sampled from its
surface (``--points`` points, then again, then 60 % as many), the body again. Prints the
process's resident set size (MB, ``/proc/self/statm``) when fresh, once the graph is loaded, and
after each task: what a worker keeps between tasks, not its peak within one.
"""

import argparse
import io
import os
from pathlib import Path

import numpy as np
import trimesh

from app.api.solver import _solve_task
from app.contract import CORRESPONDENCE_FILE
from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions
from app.inference.template import Template


def resident_mb() -> float:
    """This process's resident set size, MB."""
    pages = int(Path("/proc/self/statm").read_text().split()[1])
    return pages * os.sysconf("SC_PAGE_SIZE") / 2**20


def cloud_bytes(mesh: trimesh.Trimesh, count: int, seed: int) -> bytes:
    """``count`` points sampled from ``mesh``'s surface, as an uploaded ``.npy``."""
    points, _ = trimesh.sample.sample_surface(mesh, count, seed=seed)
    buffer = io.BytesIO()
    np.save(buffer, np.asarray(points, np.float64))
    return buffer.getvalue()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--points", type=int, default=99_000)
    args = parser.parse_args()
    settings = Settings()
    template = Template.load(settings.models_dir)
    mesh = trimesh.Trimesh(template.vertices, template.faces, process=False)
    graph = str(settings.models_dir / CORRESPONDENCE_FILE)
    body = mesh.export(file_type="ply")
    uploads = [
        ("the body, 12 k-vertex mesh", body, "ply"),
        (f"closed cloud, {args.points} points", cloud_bytes(mesh, args.points, 0), "npy"),
        (f"closed cloud, {args.points} points", cloud_bytes(mesh, args.points, 1), "npy"),
        (f"closed cloud, {int(0.6 * args.points)} points", cloud_bytes(mesh, int(0.6 * args.points), 2), "npy"),
        ("the body again", body, "ply"),
    ]
    rows = [("fresh (models' code imported)", resident_mb())]
    for name, data, file_type in uploads:
        _solve_task(data, file_type, SpectrumOptions(k=20, closed=True), False, False, graph)
        rows.append((f"after: {name}, solved and placed", resident_mb()))
    print("| worker, between tasks | resident MB |\n|---|---|")
    for name, megabytes in rows:
        print(f"| {name} | {megabytes:.0f} |")


if __name__ == "__main__":
    main()
