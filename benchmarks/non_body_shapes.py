"""Shapes that are no body part against body parts: how often the placing doubts each.

    python -m benchmarks.non_body_shapes [--people 3]

A placed part is doubted (warned, its region left out of coverage, regions and measured
overlaps: :meth:`app.inference.correspondence.CorrespondenceModel.doubts`) where its places are
uncertain or crowd onto a template region of under half its own area. Made-up shapes of 24
kinds, each at four sizes (8–50 cm) and whole or cut as a scan sees it (the faces facing one
random direction: 60 % or 35 % of them): the first 12 kinds are the ones the rule was chosen
on, the other 12 held out. Body parts: anny people's camera views (far, close-up, re-scan; as
cut and re-meshed) and random regions, for calibration people (their own seed) and Test C's
people (never trained on; the third a child). Each part is solved and placed as an upload is.

Needs the ``train`` extra (anny) and the served models in ``models/``.
"""

import argparse
from collections.abc import Callable
from pathlib import Path

import numpy as np
import trimesh

from app.geometry.pipeline import SpectrumOptions, solve_bytes
from app.inference.correspondence import PlacedPart
from app.inference.models import SpectralModels

SIZES_M = (0.08, 0.15, 0.3, 0.5)
KEPT = (1.0, 0.6, 0.35)  # whole, or the share of its faces a scan from one side keeps
REGIONS_PER_PERSON = 30
VIEW_KINDS = ("far views", "close-ups", "re-scans")  # a session's first 24 views, in scanning order


def _fine(mesh: trimesh.Trimesh, size: float) -> trimesh.Trimesh:
    """``mesh`` subdivided to edges of at most a fifteenth of ``size`` (a scan's density)."""
    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=size / 15)
    return trimesh.Trimesh(vertices, faces)


def _sheet(size: float, height: Callable[[np.ndarray, np.ndarray], np.ndarray], n: int = 60) -> trimesh.Trimesh:
    """A square sheet of side 2·``size`` lifted by ``height(x, y)``."""
    x, y = np.meshgrid(np.linspace(-size, size, n), np.linspace(-size, size, n))
    index = np.arange(n * n).reshape(n, n)
    a, b, c, d = index[:-1, :-1].ravel(), index[:-1, 1:].ravel(), index[1:, :-1].ravel(), index[1:, 1:].ravel()
    faces = np.concatenate([np.column_stack([a, b, d]), np.column_stack([a, d, c])])
    return trimesh.Trimesh(np.column_stack([x.ravel(), y.ravel(), height(x, y).ravel()]), faces)


def _displaced(size: float, rng: np.random.Generator, amplitude: float, lobes: float = 2.0) -> trimesh.Trimesh:
    """A ball of radius ``size`` pushed along its normals by a random smooth field."""
    ball = trimesh.creation.icosphere(4, radius=size)
    k = rng.normal(size=(6, 3))
    field = sum(np.sin(ball.vertices @ k[i] / size * lobes + i) for i in range(6)) / 6
    return trimesh.Trimesh(ball.vertices + amplitude * size * field[:, None] * ball.vertex_normals, ball.faces)


def _scaled_ball(size: float, axes: tuple[float, float, float]) -> trimesh.Trimesh:
    ball = trimesh.creation.icosphere(4)
    return trimesh.Trimesh(ball.vertices * np.multiply(axes, size), ball.faces)


def _dumbbell(size: float) -> trimesh.Trimesh:
    ends = [trimesh.creation.icosphere(3, radius=size / 2).apply_translation([x, 0, 0]) for x in (-size, size)]
    bar = trimesh.creation.cylinder(size / 6, 2 * size, sections=24)
    bar.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [0, 1, 0]))
    return trimesh.util.concatenate([*ends, bar])


def _chair(size: float) -> trimesh.Trimesh:
    seat = trimesh.creation.box([size, size, 0.1 * size]).apply_translation([0, 0, size])
    back = trimesh.creation.box([size, 0.1 * size, size]).apply_translation([0, size / 2, 1.5 * size])
    legs = [
        trimesh.creation.box([0.1 * size, 0.1 * size, size]).apply_translation([x, y, size / 2])
        for x in (-size / 2.2, size / 2.2)
        for y in (-size / 2.2, size / 2.2)
    ]
    return _fine(trimesh.util.concatenate([seat, back, *legs]), size)


def _mug(size: float) -> trimesh.Trimesh:
    handle = trimesh.creation.torus(size / 3, size / 12, major_sections=32, minor_sections=12)
    handle.apply_transform(trimesh.transformations.rotation_matrix(np.pi / 2, [1, 0, 0]))
    return trimesh.util.concatenate([_fine(trimesh.creation.cylinder(size / 2, size, sections=48), size), handle])


def _spiky(size: float) -> trimesh.Trimesh:
    ball = trimesh.creation.icosphere(4, radius=size)
    v = ball.vertices
    spikes = np.abs(np.sin(7 * v[:, :1] / size) * np.cos(5 * v[:, 1:2] / size)) ** 4
    return trimesh.Trimesh(v * (1 + 0.5 * spikes), ball.faces)


def _tetrahedron(size: float) -> trimesh.Trimesh:
    corners = np.array([[1, 1, 1], [-1, -1, 1], [-1, 1, -1], [1, -1, -1]]) * size
    faces = np.array([[0, 1, 2], [0, 3, 1], [0, 2, 3], [1, 3, 2]])
    return trimesh.Trimesh(*trimesh.remesh.subdivide_loop(corners, faces, iterations=5))


def shape_kinds(rng: np.random.Generator) -> dict[str, Callable[[float], trimesh.Trimesh]]:
    """Every kind of made-up shape by name, made at a characteristic length (m); the first 12
    are the calibration kinds, the rest held out."""
    return {
        "ball": lambda s: trimesh.creation.icosphere(4, radius=s),
        "capsule": lambda s: trimesh.creation.capsule(height=2 * s, radius=s / 2, count=[32, 32]),
        "box": lambda s: _fine(trimesh.creation.box([s, 1.5 * s, 0.7 * s]), s),
        "torus": lambda s: trimesh.creation.torus(s, s / 3, major_sections=64, minor_sections=32),
        "cylinder": lambda s: _fine(trimesh.creation.cylinder(s / 2, 3 * s, sections=48), s),
        "flat sheet": lambda s: _sheet(s, lambda x, y: 0 * x),
        "cone": lambda s: _fine(trimesh.creation.cone(s / 2, 2 * s, sections=48), s),
        "ellipsoid": lambda s: _scaled_ball(s, (1.0, 0.6, 0.3)),
        "blob": lambda s: _displaced(s, rng, 0.3),
        "saddle": lambda s: _sheet(s, lambda x, y: (x**2 - y**2) / s),
        "dumbbell": _dumbbell,
        "annulus": lambda s: _fine(trimesh.creation.annulus(s / 2, s, 0.05 * s, sections=64), s),
        "wavy sheet": lambda s: _sheet(s, lambda x, y: 0.15 * s * np.sin(4 * x / s) * np.cos(3 * y / s)),
        "bowl": lambda s: _sheet(s, lambda x, y: (x**2 + y**2) / s),
        "pyramid": lambda s: _fine(trimesh.creation.cone(s, s, sections=4), s),
        "rod": lambda s: trimesh.creation.capsule(height=6 * s, radius=s / 8, count=[24, 24]),
        "bumpy blob": lambda s: _displaced(s, rng, 0.6),
        "convex hull": lambda s: _fine(trimesh.convex.convex_hull(rng.normal(size=(30, 3)) * s), s),
        "bent sheet": lambda s: _sheet(s, lambda x, y: s - np.sqrt(np.maximum(s**2 - 0.8 * x**2, 0))),
        "chair": _chair,
        "mug": _mug,
        "disk": lambda s: _fine(trimesh.creation.cylinder(s, 0.03 * s, sections=64), s),
        "tetrahedron": _tetrahedron,
        "spiky ball": _spiky,
    }


CALIBRATION_KINDS = 12


def scanned(mesh: trimesh.Trimesh, kept: float, rng: np.random.Generator) -> trimesh.Trimesh:
    """``mesh`` whole, or the ``kept`` share of its faces that face one random direction most."""
    if kept >= 1.0:
        return mesh
    direction = rng.normal(size=3)
    along = mesh.triangles_center @ (direction / np.linalg.norm(direction))
    return mesh.submesh([np.flatnonzero(along >= np.quantile(along, 1 - kept))], append=True)


def placed(models: SpectralModels, vertices: np.ndarray, faces: np.ndarray) -> PlacedPart:
    """A mesh solved and placed as an upload is."""
    data = trimesh.Trimesh(vertices, faces, process=False).export(file_type="ply")
    solved = solve_bytes(data, "ply", SpectrumOptions(k=models.k), vectors=False, descriptors=True)
    return models.correspondence.placed(solved.part)


def _verdicts(part: PlacedPart) -> tuple[bool, bool, bool]:
    """Doubted at all, for uncertain places, for crowded ones."""
    return (
        not part.trusted,
        any("uncertain" in doubt for doubt in part.doubts),
        any("crowd" in doubt for doubt in part.doubts),
    )


def shape_rows(models: SpectralModels) -> dict[str, list[tuple[bool, bool, bool]]]:
    rng = np.random.default_rng(1)
    rows: dict[str, list[tuple[bool, bool, bool]]] = {"shapes, calibration kinds": [], "shapes, held-out kinds": []}
    for number, make in enumerate(shape_kinds(rng).values()):
        group = "shapes, calibration kinds" if number < CALIBRATION_KINDS else "shapes, held-out kinds"
        for size in SIZES_M:
            mesh = make(size)
            for kept in KEPT:
                part = scanned(mesh, kept, rng)
                rows[group].append(_verdicts(placed(models, np.asarray(part.vertices), np.asarray(part.faces))))
    return rows


def body_rows(models: SpectralModels, count: int) -> dict[str, list[tuple[bool, bool, bool]]]:
    from training.data.spectra import region_mesh
    from training.sessions.scans import VARIANTS, people, test_c_people, view_meshes

    rows: dict[str, list[tuple[bool, bool, bool]]] = {}
    rng = np.random.default_rng(5)
    for group, (sampler, found) in (("calibration people", people(2, 21)), ("Test C people", test_c_people(count))):
        faces = sampler.template.faces
        for person in found:
            for variant in VARIANTS:
                for number, mesh in enumerate(view_meshes(person, faces, variant)):
                    kind = VIEW_KINDS[number % 3] if number < 24 else "views from above or below"
                    rows.setdefault(f"{group}: {kind}", []).append(_verdicts(placed(models, mesh.vertices, mesh.faces)))
            for _ in range(REGIONS_PER_PERSON):
                mesh = region_mesh(person.body, faces, sampler.sample(rng).mask)
                rows.setdefault(f"{group}: random regions", []).append(
                    _verdicts(placed(models, mesh.vertices, mesh.faces))
                )
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=3, help="Test C's people (at most 9)")
    parser.add_argument("--models", default="models")
    args = parser.parse_args()
    models = SpectralModels(Path(args.models))
    rows = shape_rows(models) | body_rows(models, args.people)
    print("| parts | count | doubted (left out of coverage) | for uncertain places | for crowded places |")
    print("|---|---|---|---|---|")
    for name, verdicts in rows.items():
        share = 100 * np.mean(np.array(verdicts, dtype=float), axis=0)
        print(f"| {name} | {len(verdicts)} | {share[0]:.1f} % | {share[1]:.1f} % | {share[2]:.1f} % |")


if __name__ == "__main__":
    main()
