"""A whole scanning session's union spectrum, by each method, against the exact one.

    python -m benchmarks.session_unions [--people 4] [--variants mesh remeshed] [--seed 7]

Unseen anny people (identities drawn from their own seed, not the training's), each scanned as a
front-end does: a camera at 8 azimuths around the body, each with a far view, a close-up and a
re-scan (24 views in scanning order), then 8 views from above and below (up to 32: a view that sees
no admissible region is left out, so a length a session does not reach has no row). Views arrive as
meshes in the body's frame (registered) or re-meshed (30 % of vertices collapsed). The truth is
the spectrum of the union of the views' template masks, solved by the service's own pipeline
(pin-holes capped). Methods, mean relative error over λ₁…λ₂₀ per session length:

- ``min``: the elementwise minimum of the views' spectra (the trivial union);
- ``chain``: the served learned operator folded view by view, overlaps read from the views'
  places on the template (what ``/v1/union`` answers for unregistered uploads);
- ``chain told``: the same, told each step's overlap measured from the registered views'
  footprints (``measure_overlap=true``);
- ``fused``: the registered views fused into one cloud and solved once
  (:mod:`app.sessions.fused`).

Needs the ``train`` extra (anny) and the served models in ``models/``.
"""

import argparse
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import trimesh

from app.geometry.overlap import measured_fold
from app.geometry.pipeline import Solved, SpectrumOptions, mesh_spectrum, solve_bytes
from app.geometry.shapes import Mesh
from app.inference.models import SpectralModels
from app.sessions.chain import Located, chained_union, template_fold
from app.sessions.fused import fused_spectrum, view_of
from training.data.camera import body_mesh, close_up_camera, orbit_camera, view_mask
from training.data.regions import RegionSampler
from training.data.spectra import region_mesh, remeshed

K = 20
LENGTHS = (1, 3, 6, 12, 24, 32)
METHODS = ("min", "chain", "chain told", "fused")


@dataclass(frozen=True)
class Person:
    body: np.ndarray  # (n, 3) posed vertices, template topology
    masks: list[np.ndarray]  # the session's views as template vertex masks, in scanning order


def session_masks(sampler: RegionSampler, body: np.ndarray, rng: np.random.Generator) -> list[np.ndarray]:
    """Up to 32 views of one body in scanning order: far, close-up and re-scan at 8 azimuths,
    then 8 views alternately from above and below."""
    mesh = body_mesh(body, sampler.template.faces)
    start = rng.uniform(0, 2 * np.pi)
    cameras = []
    for step in range(8):
        azimuth = start + step * np.pi / 4
        distance, height, aim = rng.uniform(2.0, 2.5), rng.uniform(0.45, 0.75), rng.uniform(0.45, 0.55)
        far = orbit_camera(mesh, azimuth, distance, height, aim)
        moved = np.radians(rng.uniform(2, 6)) * rng.choice([-1, 1])
        cameras += [
            far,
            close_up_camera(mesh, far, rng.uniform(0.35, 0.6)),
            orbit_camera(mesh, azimuth + moved, distance + rng.uniform(-0.05, 0.05), height, aim),
        ]
    for step in range(8):
        high = step % 2 == 0
        azimuth = start + (step + 0.5) * np.pi / 4
        cameras.append(orbit_camera(mesh, azimuth, rng.uniform(1.5, 2.0), 1.3 if high else 0.05, 0.6 if high else 0.35))
    masks = [view_mask(sampler, mesh, camera) for camera in cameras]
    return [mask for mask in masks if mask is not None]


def solved_view(mesh: Mesh) -> Solved:
    """A view as the service solves an upload: spectrum, footprint and part."""
    data = trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type="ply")
    return solve_bytes(data, "ply", SpectrumOptions(k=K), vectors=False, footprint=True, descriptors=True)


def union_spectrum(body: np.ndarray, faces: np.ndarray, masks: list[np.ndarray]) -> np.ndarray:
    """The truth: the spectrum of the union of the views' template masks, as the service solves it."""
    union = region_mesh(body, faces, np.logical_or.reduce(masks))
    return np.asarray(mesh_spectrum(union, SpectrumOptions(k=K)).eigenvalues)


def relative_error(estimate: np.ndarray, truth: np.ndarray) -> float:
    return float(np.mean(np.abs(estimate - truth) / truth))


def fused(views: list[Solved]) -> np.ndarray:
    return fused_spectrum([view_of(v.part.points, v.part.mass, v.part.boundary, v.part.faces) for v in views], K)


def errors(models: SpectralModels, views: list[Solved], placed: list, truth: np.ndarray) -> dict[str, float]:
    values = [np.asarray(v.report.eigenvalues) for v in views]
    found = {"min": relative_error(np.min(values, axis=0), truth), "fused": relative_error(fused(views), truth)}
    if len(views) == 1:
        found["chain"] = found["chain told"] = relative_error(values[0], truth)
        return found
    chained = chained_union(models, values, template_fold(models, [Located.placed(part) for part in placed]))
    found["chain"] = relative_error(chained.eigenvalues, truth)
    fold = measured_fold([v.footprint for v in views])
    measured = models.union(values, fold.overlaps, fold.boundaries if models.reads_boundary else None)
    found["chain told"] = relative_error(measured.eigenvalues, truth)
    return found


def people(count: int, seed: int) -> tuple[RegionSampler, list[Person]]:
    """``count`` unseen anny people (half men, half women) in one random pose each, and their sessions."""
    from training.data.bodies import AnnySource

    source = AnnySource()
    sampler = RegionSampler(source.template())
    found = []
    for number, label in enumerate(("man", "woman")):
        share = count // 2 + (count % 2 if number == 0 else 0)
        if share == 0:  # anny draws no empty batch
            continue
        identities = source.body.sample_identities(seed * 100 + number, label, f"unknown_{label}", share)
        for index, identity in enumerate(identities):
            rng = np.random.default_rng([seed, number, index])
            body = source.body.pose(identity, source.body.valid_poses(identity, rng, 1, rest_first=False))[0]
            found.append(Person(np.asarray(body, np.float64), session_masks(sampler, body, rng)))
    return sampler, found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=4)
    parser.add_argument("--variants", nargs="+", default=["mesh", "remeshed"], choices=["mesh", "remeshed"])
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--models", default="models")
    args = parser.parse_args()
    models = SpectralModels(Path(args.models))
    sampler, found = people(args.people, args.seed)
    faces = sampler.template.faces
    table: dict[tuple[str, int], list[dict[str, float]]] = {}
    for person in found:
        for variant in args.variants:
            meshes = [region_mesh(person.body, faces, mask) for mask in person.masks]
            views = [solved_view(remeshed(m) if variant == "remeshed" else m) for m in meshes]
            placed = [models.correspondence.placed(v.part) for v in views]
            for length in LENGTHS:
                if length > len(views):
                    continue
                truth = union_spectrum(person.body, faces, person.masks[:length])
                table.setdefault((variant, length), []).append(errors(models, views[:length], placed[:length], truth))
                print(variant, length, {k: round(v, 4) for k, v in table[(variant, length)][-1].items()}, flush=True)
    print("\n| views | delivery | sessions | " + " | ".join(METHODS) + " |")
    print("|---|---|---|" + "---|" * len(METHODS))
    for (variant, length), rows in sorted(table.items(), key=lambda item: (item[0][1], item[0][0])):
        cells = " | ".join(f"{100 * np.mean([row[m] for row in rows]):.1f} %" for m in METHODS)
        print(f"| {length} | {variant} | {len(rows)} | {cells} |")


if __name__ == "__main__":
    main()
