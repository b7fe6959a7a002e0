"""Parts whose place on the template is known: anny bodies cut as scans are, with the template
vertex of every vertex, as the correspondence model trains and is scored on.

Every anny body shares the template's topology, so a part cut from a posed body by a template
mask knows each vertex's template vertex exactly. Parts are cut the two ways scans come: random
regions (:class:`~training.data.regions.RegionSampler`: parts removed, balls, plane cuts, holes,
smooth fields) and what a depth camera sees from around the body or close up
(:mod:`training.data.camera`). Each then arrives as a mesh, re-meshed (30 % of its vertices
collapsed), or as a point cloud with its boundary flagged, sometimes with sensor noise; every
variant passes the service's own checks (``prepare_mesh``/``prepare_cloud``) and descriptors
(:mod:`app.geometry.descriptors`), and a vertex that is not a body vertex (re-meshed, noisy, a
pin-hole's centre) takes the template vertex of the nearest vertex of the posed region.

Sets: ``train`` (training identities and poses), ``test_a`` (training identities in held-out
poses), ``test_b`` (identities never trained on, random regions) and ``test_c`` (identities
never trained on, camera views). Each part is one ``.npz`` in ``<out>/parts``, drawn from its own
stream ``[seed, set, index]``, so a killed build resumes and every part is the same whichever
worker draws it.
"""

import json
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import trimesh
from scipy.spatial import cKDTree
from threadpoolctl import threadpool_limits

from app.contract import CORRESPONDENCE_BASIS, MAX_HOLE_EDGES
from app.geometry import (
    GeometryError,
    Mesh,
    PartInputs,
    PointCloud,
    boundary_vertex_mask,
    cloud_inputs,
    mesh_inputs,
    prepare_cloud,
    prepare_mesh,
    referenced,
)
from app.inference import faces_inside
from training.data.camera import (
    CLOSE_UP_DISTANCE,
    DISTANCE,
    body_mesh,
    close_up_camera,
    orbit_camera,
    view_mask,
)
from training.data.spectra import CLOUD, MESH, REMESHED, remeshed
from training.data.workers import mapped, run_tasks, sampler_of

SETS = ("train", "test_a", "test_b", "test_c")
VARIANTS = (MESH, REMESHED, CLOUD)
TRAIN_VARIANT_SHARES = (0.6, 0.25, 0.15)  # mesh, re-meshed, cloud
CAMERA_SHARE = 0.5  # of training parts: camera views; the rest random regions
NOISE_SHARE = 0.3  # of training parts: vertices moved by sensor noise
NOISE_M = 0.0015  # a depth camera's ~1.5 mm at arm's length


@dataclass(frozen=True, kw_only=True)
class PartsPreset:
    """Sizes of a parts build. Identities are split evenly between men and women."""

    name: str
    train_identities: int
    test_identities: int
    poses: int  # per identity; the last one is held out for test_a
    train_parts: int
    test_parts: int  # per test set and variant
    test_pairs: int  # draws per pair set (a region pair, or a session's five pairs)

    def __post_init__(self) -> None:
        # A validation pair puts its parts on two of a training person's training poses (all but
        # the last), as a test pair does on two of an unseen person's.
        if self.poses < 3:
            raise ValueError(f"a parts build needs at least 3 poses per identity, not {self.poses}")


PARTS_PRESETS = {
    preset.name: preset
    for preset in (
        PartsPreset(
            name="tiny", train_identities=2, test_identities=2, poses=3, train_parts=12, test_parts=2, test_pairs=2
        ),
        PartsPreset(
            name="standard",
            train_identities=24,
            test_identities=8,
            poses=6,
            train_parts=3600,
            test_parts=40,
            test_pairs=60,
        ),
    )
}


@dataclass(frozen=True)
class Plan:
    """What one part is: its set, which body (row of shapes.npy), how it is cut and how it arrives."""

    set: str
    index: int
    shape: int
    cut: str  # "region" or "camera"
    variant: str
    noisy: bool


def build_parts(preset: PartsPreset, out: Path, seed: int = 0, workers: int | None = None) -> dict:
    """Bodies, then every planned part not yet saved; returns the build's manifest."""
    from training.data.bodies import AnnySource
    from training.data.presets import ShapeGroup

    out.mkdir(parents=True, exist_ok=True)
    (out / "parts").mkdir(exist_ok=True)
    shapes_path = out / "shapes.npy"
    template_dir = out / "template"
    if not shapes_path.exists():
        source = AnnySource()
        source.template().save(template_dir, source.description)
        half_train, half_test = preset.train_identities // 2, preset.test_identities // 2
        groups = [
            ShapeGroup("known_man", half_train),
            ShapeGroup("known_woman", preset.train_identities - half_train),
            ShapeGroup("unknown_man", half_test),
            ShapeGroup("unknown_woman", preset.test_identities - half_test),
        ]
        shapes, _ = source.shapes(groups, preset.poses, seed)
        np.save(shapes_path, shapes.reshape(-1, *shapes.shape[2:]).astype(np.float32))
    plans = plan_parts(preset, seed)
    missing = [plan for plan in plans if not part_path(out, plan).exists()]
    arguments = [(str(template_dir), str(shapes_path), str(out), seed, plan) for plan in missing]
    run_tasks(draw_part, arguments, lambda index, result: None, None, workers, "parts")
    manifest = {"preset": asdict(preset), "seed": seed, "parts": {s: sum(p.set == s for p in plans) for s in SETS}}
    (out / "parts.json").write_text(json.dumps(manifest, indent=1) + "\n")
    return manifest


def plan_parts(preset: PartsPreset, seed: int) -> list[Plan]:
    """Every part of the build, in a fixed order, from the plan's own stream."""
    rng = np.random.default_rng([seed, 0xC0 + 1])
    poses = preset.poses
    train_bodies = [i * poses + p for i in range(preset.train_identities) for p in range(poses - 1)]
    held_out = [i * poses + poses - 1 for i in range(preset.train_identities)]
    unknown = range(preset.train_identities, preset.train_identities + preset.test_identities)
    unseen = [i * poses + p for i in unknown for p in range(poses)]
    plans = []
    for index in range(preset.train_parts):
        cut = "camera" if rng.random() < CAMERA_SHARE else "region"
        variant = str(rng.choice(VARIANTS, p=TRAIN_VARIANT_SHARES))
        plans.append(
            Plan("train", index, int(rng.choice(train_bodies)), cut, variant, bool(rng.random() < NOISE_SHARE))
        )
    rng = np.random.default_rng([seed, 0xC0 + 3])  # the test sets' own stream: the same whatever is trained on
    tests = (("test_a", held_out, None), ("test_b", unseen, "region"), ("test_c", unseen, "camera"))
    for name, bodies, only in tests:
        index = 0
        for variant in VARIANTS:
            for _ in range(preset.test_parts):
                cut = only or ("camera" if rng.random() < CAMERA_SHARE else "region")
                plans.append(Plan(name, index, int(rng.choice(bodies)), cut, variant, False))
                index += 1
    return plans


def part_path(out: Path, plan: Plan) -> Path:
    return out / "parts" / f"{plan.set}-{plan.index:05d}.npz"


@threadpool_limits.wrap(limits=1)
def draw_part(template_dir: str, shapes_path: str, out: str, seed: int, plan: Plan) -> None:
    """Cut, deliver and describe one part; saves its inputs and targets (retries its draw until
    the service's checks accept the part)."""
    sampler = sampler_of(template_dir)
    body = np.asarray(mapped(shapes_path)[plan.shape], dtype=np.float64)
    rng = np.random.default_rng([seed, SETS.index(plan.set) + 1, plan.index])
    while True:
        mask = _cut(plan.cut, sampler, body, rng)
        try:
            inputs, target = part_of(body, sampler.template.faces, mask, plan.variant, plan.noisy, rng)
            break
        except GeometryError:
            continue
    # A test part keeps its geometry too: the evaluation places it as the service does, which
    # may read a simplified copy of it (app.geometry.placing); training reads only its inputs.
    geometry = {} if plan.set == "train" else part_geometry(inputs)
    np.savez(
        part_path(Path(out), plan),
        target=target,
        mask=np.packbits(mask),
        shape=plan.shape,
        cut=plan.cut,
        variant=plan.variant,
        **inputs.feeds(),
        **geometry,
    )


def part_geometry(inputs: PartInputs) -> dict[str, np.ndarray]:
    """A delivered part's points and a mesh's faces (none for a point cloud), as saved."""
    faces = np.empty((0, 3), np.int64) if inputs.faces is None else inputs.faces
    return {"points": inputs.points, "faces": faces}


def _cut(cut: str, sampler, body: np.ndarray, rng: np.random.Generator) -> np.ndarray:
    """A template mask: a random region, or what a random camera sees (orbit or close-up)."""
    if cut == "region":
        return sampler.sample(rng).mask
    mesh = _body_mesh(body.tobytes(), sampler)
    while True:
        camera = orbit_camera(
            mesh, rng.uniform(0, 2 * np.pi), rng.uniform(*DISTANCE), rng.uniform(0.2, 1.1), rng.uniform(0.3, 0.8)
        )
        if rng.random() < 0.25:
            camera = close_up_camera(mesh, camera, rng.uniform(*CLOSE_UP_DISTANCE))
        mask = view_mask(sampler, mesh, camera)
        if mask is not None:
            return mask


@lru_cache(maxsize=1)
def _body_mesh(key: bytes, sampler) -> trimesh.Trimesh:
    """The posed body as trimesh (with its ray caster), kept while parts of it are drawn."""
    return body_mesh(np.frombuffer(key).reshape(-1, 3), sampler.template.faces)


def part_of(
    body: np.ndarray,
    faces: np.ndarray,
    mask: np.ndarray,
    variant: str,
    noisy: bool = False,
    rng: np.random.Generator | None = None,
) -> tuple[PartInputs, np.ndarray]:
    """The inputs of the part of ``body`` inside ``mask`` as ``variant`` delivers it, and each of
    its vertices' template vertex (the nearest vertex of the posed region)."""
    inside = faces[faces_inside(mask, faces)]
    used = referenced(inside, len(body))
    region = np.flatnonzero(used)
    mesh = Mesh(body[region], (np.cumsum(used) - 1)[inside])
    if variant == REMESHED:
        mesh = remeshed(mesh)
    if noisy:  # ``rng`` draws the noise
        mesh = Mesh(mesh.vertices + rng.normal(0, NOISE_M, mesh.vertices.shape), mesh.faces)
    if variant == CLOUD:
        boundary = boundary_vertex_mask(mesh.faces, len(mesh.vertices))
        prepared = prepare_cloud(
            PointCloud(mesh.vertices, boundary),
            k=CORRESPONDENCE_BASIS,
            closed=not boundary.any(),
            boundary_indices=None,
        )
        inputs = cloud_inputs(prepared.cloud.points, prepared.boundary)
        points = prepared.cloud.points
    else:
        prepared_mesh = prepare_mesh(mesh, k=CORRESPONDENCE_BASIS, max_hole_edges=MAX_HOLE_EDGES)
        points = prepared_mesh.mesh.vertices
        inputs = mesh_inputs(points, prepared_mesh.mesh.faces)
    _, nearest = cKDTree(body[region]).query(points)
    return inputs, region[nearest]
