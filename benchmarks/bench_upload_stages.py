"""Where an upload's solve goes, stage by stage, as a solver worker runs it (one BLAS thread).

Run: ``python benchmarks/bench_upload_stages.py [FILE ...] [--k 20] [--repeats 9]`` (default
files: the README's sample scans, written by ``spectral-unions samples``). Prints a Markdown
table of median milliseconds per file: parsing the bytes (``load_shape``), the checks and
repairs (``prepare_mesh``: merging, repeated and degenerate faces, the largest component,
pin-holes), the intrinsic-Delaunay Laplacian, the shifted LDLᵀ factorization and ARPACK's
iteration: the stages of one solve timed together in each repeat, so a drift of this VM's speed
moves them alike. Beside them, the floor the checks and the Laplacian are measured against: one
pass over the parsed arrays (a sum of the vertices' and of the faces' entries), what any code
that reads the mesh once must cost.
"""

import argparse
import statistics
import tempfile
import time
from pathlib import Path

from threadpoolctl import threadpool_limits

from app.contract import MAX_HOLE_EDGES
from app.geometry.io import load_shape, resolve_file_type
from app.geometry.laplacian import mesh_operators
from app.geometry.pencil import ShiftedPencil
from app.geometry.shapes import Mesh
from app.geometry.validate import prepare_mesh
from app.inference.template import Template
from app.samples import write_samples

STAGES = ("parse", "checks", "laplacian", "factorization", "iteration")
FLOOR = "one pass"


def stage_times(data: bytes, file_type: str, k: int) -> dict[str, float]:
    """Milliseconds of each stage of one solve of ``data``."""
    marks = [time.perf_counter()]
    shape = load_shape(data, file_type, scale=1.0, max_vertices=10**7)
    if not isinstance(shape, Mesh):
        raise SystemExit("meshes only: a point cloud's stages are others")
    marks.append(time.perf_counter())
    prepared = prepare_mesh(shape, k=k, max_hole_edges=MAX_HOLE_EDGES)
    marks.append(time.perf_counter())
    operators = mesh_operators(prepared.mesh.vertices, prepared.mesh.faces)
    marks.append(time.perf_counter())
    pencil = ShiftedPencil(operators, prepared.boundary if prepared.boundary.any() else None)
    factor = pencil.factor(pencil.lowest_shift)
    marks.append(time.perf_counter())
    pencil.nearest(factor, k)
    marks.append(time.perf_counter())
    return {stage: 1e3 * (end - start) for stage, start, end in zip(STAGES, marks[:-1], marks[1:], strict=True)}


def one_pass_ms(mesh: Mesh) -> float:
    """Milliseconds of one read of the mesh's arrays, each summed once."""
    started = time.perf_counter()
    mesh.vertices.sum()
    mesh.faces.sum()
    return 1e3 * (time.perf_counter() - started)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("files", type=Path, nargs="*")
    parser.add_argument("--k", type=int, default=20)
    parser.add_argument("--repeats", type=int, default=9)
    parser.add_argument("--models", type=Path, default=Path("models"), help="the template the samples are cut from")
    args = parser.parse_args()
    files = args.files
    if not files:
        folder = Path(tempfile.mkdtemp(prefix="samples-"))
        files = [p for p in write_samples(folder, Template.load(args.models)) if p.suffix == ".ply"]
    print(f"| file | {FLOOR} | {' | '.join(STAGES)} | total |")
    print("|---|" + "---|" * (len(STAGES) + 2))
    with threadpool_limits(limits=1):
        for path in files:
            data, file_type = path.read_bytes(), resolve_file_type(path.name, None)
            mesh = load_shape(data, file_type, scale=1.0, max_vertices=10**7)
            stage_times(data, file_type, args.k)  # warm-up
            runs = [stage_times(data, file_type, args.k) | {FLOOR: one_pass_ms(mesh)} for _ in range(args.repeats)]
            medians = [statistics.median(run[stage] for run in runs) for stage in (FLOOR, *STAGES)]
            cells = " | ".join(f"{value:.2f}" if value < 1 else f"{value:.1f}" for value in medians)
            total = statistics.median(sum(run[stage] for stage in STAGES) for run in runs)
            print(f"| {path.name} | {cells} | {total:.1f} |", flush=True)


if __name__ == "__main__":
    main()
