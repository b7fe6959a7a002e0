"""Spectrum engine speed against LaPy's default and its strongest configuration, end to end.

Run: ``python benchmarks/bench_spectrum.py`` (needs ``pip install -e '.[train,dev]'`` for
anny, fast-simplification, LaPy and cholespy). Prints, as a Markdown table, median-of-N
milliseconds on closed anny bodies of ~5 k and ~13 k vertices (and ~53 k with ``--large``) and
an ~8 k-vertex Dirichlet region and a ~6 k-vertex depth-camera view (the data build's ray
casting), at k = 20 and 128 by default: our engine split into assembly (the
intrinsic-Delaunay Laplacian), factorization (the shifted LDLᵀ) and iteration (ARPACK, by
difference from the total), LaPy with SciPy's SuperLU (its default) and LaPy with CHOLMOD
(``use_cholmod=True``, through the cholespy wheel), each assembly and solve together, in one
run on one machine; and how far our eigenvalues are from a plain SciPy solve of the same
matrices. LaPy has no Dirichlet option, so on the region it solves the Neumann problem (the
same matrix sizes and the same work).

``--eigenbasis`` times instead eigenvalues with their eigenfunctions (k = 64 and 128 by
default), as the correspondence model's inputs need them: ours on the free-boundary (Neumann)
problem, and on shapes with a boundary the Dirichlet one as served, against LaPy-CHOLMOD, whose
solve always returns them.

``--http`` measures instead what a client sees: ``POST /v1/spectrum`` of the 13 k body to the
service started on its embedded defaults (its solver workers on one BLAS thread each), one
request at a time, beside LaPy-CHOLMOD in this process.
"""

import argparse
from functools import partial

import fast_simplification
import httpx
import lapy
import numpy as np
import scipy.sparse.linalg as sla
import trimesh

from app.geometry.laplacian import Operators, mesh_operators
from app.geometry.pencil import ShiftedPencil
from app.geometry.shapes import Mesh
from app.geometry.spectrum import eigenpairs, eigenvalues, shift_for
from app.geometry.topology import boundary_vertex_mask, drop_unreferenced, largest_component
from training.common.timing import interleaved_ms


def anny_body() -> Mesh:
    """The neutral anny body in its rest pose (13 348 vertices, watertight)."""
    import anny

    model = anny.Anny(topology="anny-noeyes-notongue")
    vertices = model()["vertices"][0].detach().double().numpy()
    faces = model.get_triangular_faces().numpy().astype(np.int64)
    return Mesh(*drop_unreferenced(vertices, faces))


def camera_view(body: Mesh) -> Mesh:
    """What a depth camera 1.8 m in front of the body sees: the data build's ray casting, its
    largest component (~6 k vertices, a boundary all round)."""
    from training.data.camera import body_mesh, orbit_camera, visible_vertices

    mesh = body_mesh(body.vertices, body.faces)
    seen = visible_vertices(mesh, orbit_camera(mesh, azimuth=-np.pi / 2, distance=1.8, height=0.6, aim=0.5))
    faces, _ = largest_component(body.vertices, body.faces[seen[body.faces].all(axis=1)])
    return Mesh(*drop_unreferenced(body.vertices, faces))


def bodies(large: bool) -> dict[str, tuple[Mesh, np.ndarray | None]]:
    """The benchmark shapes, each with its Dirichlet vertices (None = closed)."""
    body = anny_body()
    coarse_v, coarse_f = fast_simplification.simplify(body.vertices, body.faces, target_reduction=0.62)
    # The upper body above the hips: one region with a boundary, ~8 k vertices.
    height = body.vertices[:, 2]
    keep = body.faces[height[body.faces].min(axis=1) > np.quantile(height, 0.4)]
    region_faces, _ = largest_component(body.vertices, keep)
    region = Mesh(*drop_unreferenced(body.vertices, region_faces))
    shapes = {
        "closed body, decimated": (Mesh(coarse_v.astype(np.float64), coarse_f.astype(np.int64)), None),
        "closed body": (body, None),
        "Dirichlet region": (region, boundary_vertex_mask(region.faces, len(region.vertices))),
    }
    view = camera_view(body)
    shapes["camera view"] = (view, boundary_vertex_mask(view.faces, len(view.vertices)))
    if large:
        fine = trimesh.Trimesh(body.vertices, body.faces, process=False).subdivide()
        shapes["closed body, subdivided"] = (Mesh(np.asarray(fine.vertices), np.asarray(fine.faces)), None)
    return shapes


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


def lapy_cholmod(mesh: Mesh, k: int) -> None:
    """LaPy's strongest configuration, assembly and solve."""
    lapy.Solver(lapy.TriaMesh(mesh.vertices, mesh.faces), use_cholmod=True).eigs(k)


def factorization(operators: Operators, fixed: np.ndarray | None) -> None:
    """One factorization of the shifted system, at the lowest shift (a sliced solve makes one
    per slice, counted in its iteration)."""
    pencil = ShiftedPencil(operators, fixed)
    pencil.factor(pencil.lowest_shift)


def measure(mesh: Mesh, fixed: np.ndarray | None, k: int, repeats: int) -> dict[str, float]:
    """Medians in ms for our engine's steps and LaPy's two configurations, and our deviation
    from plain SciPy."""
    v, f = mesh.vertices, mesh.faces
    operators = mesh_operators(v, f)
    times = interleaved_ms(
        {
            "assembly": partial(mesh_operators, v, f),
            "factorization": partial(factorization, operators, fixed),
            "total": lambda: eigenvalues(mesh_operators(v, f), k, fixed),
            "lapy_superlu": lambda: lapy.Solver(lapy.TriaMesh(v, f)).eigs(k),
            "lapy_cholmod": partial(lapy_cholmod, mesh, k),
        },
        repeats,
    )
    times["iteration"] = times["total"] - times["assembly"] - times["factorization"]
    deviation = relative_deviation(eigenvalues(operators, k, fixed), scipy_reference(mesh, fixed, k))
    return {**times, "deviation": deviation}


def eigenbasis(mesh: Mesh, fixed: np.ndarray | None, k: int) -> None:
    """Our assembly and solve of ``k`` eigenpairs, with x = 0 on ``fixed``."""
    eigenpairs(mesh_operators(mesh.vertices, mesh.faces), k, fixed, vectors=True)


def eigenbasis_table(shapes: dict[str, tuple[Mesh, np.ndarray | None]], ks: list[int], repeats: int) -> None:
    """Eigenvalues with eigenfunctions, ours (Neumann, and Dirichlet where the shape has a
    boundary) against LaPy-CHOLMOD, each assembly and solve together, as a Markdown table."""
    print(
        "| shape | n | k | ours, Neumann | ours, Dirichlet | LaPy CHOLMOD | ×CHOLMOD (Neumann) | ×CHOLMOD (Dirichlet) |"
    )
    print("|---|---|---|---|---|---|---|---|")
    for name, (mesh, fixed) in shapes.items():
        for k in ks:
            runs = {"neumann": partial(eigenbasis, mesh, None, k), "cholmod": partial(lapy_cholmod, mesh, k)}
            if fixed is not None:
                runs["dirichlet"] = partial(eigenbasis, mesh, fixed, k)
            t = interleaved_ms(runs, repeats)
            dirichlet = t.get("dirichlet")
            cells = ("—", "—") if dirichlet is None else (f"{dirichlet:.0f}", f"{t['cholmod'] / dirichlet:.2f}")
            print(
                f"| {name} | {len(mesh.vertices)} | {k} | {t['neumann']:.0f} | {cells[0]} | {t['cholmod']:.0f} "
                f"| {t['cholmod'] / t['neumann']:.2f} | {cells[1]} |",
                flush=True,
            )


def over_http(mesh: Mesh, ks: list[int], repeats: int, port: int) -> None:
    """``POST /v1/spectrum`` of ``mesh`` (PLY) to the service started on its embedded defaults,
    one client, against LaPy-CHOLMOD in process, as a Markdown table."""
    from benchmarks.load import start_server, stop_server

    data = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type="ply")
    url = f"http://127.0.0.1:{port}/v1/spectrum"
    server = start_server(port)
    print("| shape | n | k | ours over HTTP | LaPy CHOLMOD in process | ×CHOLMOD | max rel. dev. from in process |")
    print("|---|---|---|---|---|---|---|")
    try:
        with httpx.Client(timeout=120) as http:
            for k in ks:
                post = partial(http.post, url, params={"k": k}, files={"file": ("body.ply", data)})
                served = np.array(post().raise_for_status().json()["eigenvalues"])
                times = interleaved_ms({"ours": post, "cholmod": partial(lapy_cholmod, mesh, k)}, repeats)
                ours, cholmod = times["ours"], times["cholmod"]
                deviation = relative_deviation(served, eigenvalues(mesh_operators(mesh.vertices, mesh.faces), k))
                print(
                    f"| closed body | {len(mesh.vertices)} | {k} | {ours:.0f} | {cholmod:.0f} | {cholmod / ours:.2f} "
                    f"| {deviation:.1e} |",
                    flush=True,
                )
    finally:
        stop_server(server)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=5)
    parser.add_argument("--k", type=int, nargs="+", help="default: 20 128 (64 128 with --eigenbasis)")
    parser.add_argument("--large", action="store_true", help="also the ~53 k-vertex subdivided body")
    parser.add_argument("--http", action="store_true", help="instead: the service's /v1/spectrum of the body")
    parser.add_argument("--eigenbasis", action="store_true", help="instead: eigenvalues with their eigenfunctions")
    parser.add_argument("--port", type=int, default=8766, help="with --http")
    args = parser.parse_args()
    if args.eigenbasis:
        eigenbasis_table(bodies(args.large), args.k or [64, 128], args.repeats)
        return
    ks = args.k or [20, 128]
    if args.http:
        over_http(anny_body(), ks, args.repeats, args.port)
        return
    print(
        "| shape | n | k | ours: assembly | factorization | iteration | total | LaPy SuperLU | LaPy CHOLMOD "
        "| ×SuperLU | ×CHOLMOD | max rel. dev. from SciPy |"
    )
    print("|---|---|---|---|---|---|---|---|---|---|---|---|")
    for name, (mesh, fixed) in bodies(args.large).items():
        for k in ks:
            r = measure(mesh, fixed, k, args.repeats)
            print(
                f"| {name} | {len(mesh.vertices)} | {k} | {r['assembly']:.0f} | {r['factorization']:.0f} "
                f"| {r['iteration']:.0f} | {r['total']:.0f} | {r['lapy_superlu']:.0f} | {r['lapy_cholmod']:.0f} "
                f"| {r['lapy_superlu'] / r['total']:.2f} | {r['lapy_cholmod'] / r['total']:.2f} "
                f"| {r['deviation']:.1e} |",
                flush=True,
            )


if __name__ == "__main__":
    main()
