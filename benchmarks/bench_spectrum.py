"""Spectrum engine speed against LaPy, end to end (assembly + solve), on anny bodies.

Run: ``python benchmarks/bench_spectrum.py`` (needs ``pip install -e '.[train,dev]'`` for
anny, fast-simplification and LaPy). Prints median-of-N milliseconds for closed bodies of
~5 k, ~13 k and ~53 k vertices and an ~8 k-vertex Dirichlet region, k = 20 and 30, our
engine and LaPy side by side, and how far our eigenvalues are from a plain SciPy solve of the
same matrices. LaPy has no Dirichlet option, so on the region it solves the Neumann problem
(the same matrix sizes and the same work).
"""

import argparse
import statistics
import time
from collections.abc import Callable

import fast_simplification
import lapy
import numpy as np
import scipy.sparse.linalg as sla
import trimesh

from app.geometry.laplacian import mesh_operators
from app.geometry.shapes import Mesh
from app.geometry.spectrum import eigenvalues, shift_for
from app.geometry.topology import boundary_vertex_mask, drop_unreferenced, largest_component


def anny_body() -> Mesh:
    """The neutral anny body in its rest pose (13 348 vertices, watertight)."""
    import anny

    model = anny.Anny(topology="anny-noeyes-notongue")
    vertices = model()["vertices"][0].detach().double().numpy()
    faces = model.get_triangular_faces().numpy().astype(np.int64)
    return Mesh(*drop_unreferenced(vertices, faces))


def bodies() -> dict[str, tuple[Mesh, np.ndarray | None]]:
    """The benchmark shapes, each with its Dirichlet vertices (None = closed)."""
    body = anny_body()
    fine = trimesh.Trimesh(body.vertices, body.faces, process=False).subdivide()
    coarse_v, coarse_f = fast_simplification.simplify(body.vertices, body.faces, target_reduction=0.62)
    # The upper body above the hips: one region with a boundary, ~8 k vertices.
    height = body.vertices[:, 2]
    keep = body.faces[height[body.faces].min(axis=1) > np.quantile(height, 0.4)]
    region_faces, _ = largest_component(body.vertices, keep)
    region = Mesh(*drop_unreferenced(body.vertices, region_faces))
    return {
        "closed body, decimated": (Mesh(coarse_v.astype(np.float64), coarse_f.astype(np.int64)), None),
        "closed body": (body, None),
        "closed body, subdivided": (Mesh(np.asarray(fine.vertices), np.asarray(fine.faces)), None),
        "Dirichlet region": (region, boundary_vertex_mask(region.faces, len(region.vertices))),
    }


def median_ms(run: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append(time.perf_counter() - started)
    return 1e3 * statistics.median(times)


def scipy_reference(mesh: Mesh, fixed: np.ndarray | None, k: int) -> np.ndarray:
    """A plain SciPy shift-invert solve (SuperLU inside) of our very matrices."""
    stiffness, mass = mesh_operators(mesh.vertices, mesh.faces)
    if fixed is not None:
        free = np.flatnonzero(~fixed)
        stiffness, mass = stiffness[free][:, free], mass[free][:, free]
    return np.sort(sla.eigsh(stiffness, k, mass, sigma=shift_for(mass))[0])


def relative_deviation(values: np.ndarray, reference: np.ndarray) -> float:
    """Largest per-eigenvalue relative difference; a zero eigenvalue is measured against λ_k."""
    scale = np.where(np.abs(reference) > 1e-9 * reference[-1], np.abs(reference), reference[-1])
    return float(np.max(np.abs(values - reference) / scale))


def measure(mesh: Mesh, fixed: np.ndarray | None, k: int, repeats: int) -> dict[str, float]:
    """Medians in ms for our engine and LaPy, and our deviation from plain SciPy."""
    v, f = mesh.vertices, mesh.faces
    operators = mesh_operators(v, f)
    solver = lapy.Solver(lapy.TriaMesh(v, f))
    return {
        "ours_asm": median_ms(lambda: mesh_operators(v, f), repeats),
        "ours_solve": median_ms(lambda: eigenvalues(operators, k, fixed), repeats),
        "ours_total": median_ms(lambda: eigenvalues(mesh_operators(v, f), k, fixed), repeats),
        "lapy_asm": median_ms(lambda: lapy.Solver(lapy.TriaMesh(v, f)), repeats),
        "lapy_solve": median_ms(lambda: solver.eigs(k), repeats),
        "lapy_total": median_ms(lambda: lapy.Solver(lapy.TriaMesh(v, f)).eigs(k), repeats),
        "deviation": relative_deviation(eigenvalues(operators, k, fixed), scipy_reference(mesh, fixed, k)),
    }


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    args = parser.parse_args()
    header = (
        f"{'shape':<26}{'n':>7}{'k':>4} | {'ours asm':>9}{'solve':>8}{'total':>8} | "
        f"{'LaPy asm':>9}{'solve':>8}{'total':>8} | {'speed-up':>8} | {'max rel. dev.':>13}"
    )
    print(header)
    print("-" * len(header))
    for name, (mesh, fixed) in bodies().items():
        for k in (20, 30):
            r = measure(mesh, fixed, k, args.repeats)
            print(
                f"{name:<26}{len(mesh.vertices):>7}{k:>4} | "
                f"{r['ours_asm']:>9.1f}{r['ours_solve']:>8.1f}{r['ours_total']:>8.1f} | "
                f"{r['lapy_asm']:>9.1f}{r['lapy_solve']:>8.1f}{r['lapy_total']:>8.1f} | "
                f"{r['lapy_total'] / r['ours_total']:>7.2f}x | {r['deviation']:>13.1e}"
            )


if __name__ == "__main__":
    main()
