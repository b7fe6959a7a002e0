"""Build the benchmark: shapes, region pairs and triples, splits, spectra; resumable and parallel.

Stages, each saved under ``<out>/work`` before the next starts, so a killed build resumes
where it stopped: (1) posed shapes from a :class:`ShapeSource`; (2) masks of pairs and
triples, drawn in parallel chunks with per-chunk seeds; (3) splits and the Test B filter;
(4) spectra of every distinct (shape, mask, variant), in parallel chunks. The same task
functions run on a local process pool or, given a scheduler address, on a Dask cluster.
Everything is a function of the preset and one seed.
"""

import hashlib
import json
import time
from collections.abc import Callable, Iterable, Sequence
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field
from functools import lru_cache
from pathlib import Path
from typing import Protocol

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from training.data.camera import scan_session
from training.data.overlaps import CHAIN_COLUMNS, SESSION_VIEWS, TEST_C_GROUPS, derived_rows, session_rows
from training.data.pairs import (
    FULL_COVERAGE,
    OVERLAP,
    PARTIAL_UNION,
    Pair,
    sample_pair,
    sample_triple,
    split_union,
    symmetric_iou,
)
from training.data.regions import RegionSampler
from training.data.rows import Rows, poses_for
from training.data.samples import export_samples
from training.data.spectra import CLOUD, MESH, REMESHED, VARIANTS, task_spectrum
from training.data.template import Template

# Per-kind seed word. "candidate" and "triple" share one: a candidate chunk's first draw may repeat
# the union of the same chunk's first triple. Harmless, so kept (a new word would redraw every
# Test B union and the committed tables with them): candidates are only offered as Test B union
# types, and one that equals a triple's union has IoU 1 with a seen union, so the novelty filter
# (_held_out_unions, IoU < 0.8 with every training and triple union) always drops it.
MASK_STREAMS = {"pair": 0, "candidate": 1, "triple": 1, "retrieval": 2, "overlap": 3}
TEST_B_MAX_IOU = 0.8  # a Test B union overlaps every training union (or its mirror) less than this
TEST_B_TYPES = 30  # held-out union types, each realized by many different pairs
SPLIT_ATTEMPTS = 20  # tries per wanted Test B pair


@dataclass(frozen=True)
class Preset:
    """Sizes of a build. ``test_pairs`` is per test group and per test set (A and B)."""

    name: str
    known_men: int
    known_women: int
    unknown_men: int
    unknown_women: int
    children: int
    poses: int
    test_poses: int  # the last poses of known identities are held out for Test A
    train_pairs: int
    test_pairs: int
    triples: int
    cloud_parts: int
    chunk: int
    k: int = 20
    retrieval_pairs: int = 0  # full-coverage pairs on held-out poses and identities: identity queries only
    # Pairs that overlap as scans do (training.data.overlaps): two parts of one region (training,
    # and per Test A group), identical/rescan/nested pairs of each kind (training, per Test A
    # group), and scanning sessions (training, and per Test C group).
    overlap_pairs: int = 0
    overlap_test: int = 0
    derived_pairs: int = 0
    derived_test: int = 0
    train_sessions: int = 0
    test_sessions: int = 0


PRESETS = {
    "tiny": Preset(
        "tiny",
        2,
        1,
        1,
        1,
        1,
        poses=3,
        test_poses=1,
        train_pairs=24,
        test_pairs=2,
        triples=4,
        cloud_parts=2,
        chunk=8,
        retrieval_pairs=5,
        overlap_pairs=12,
        overlap_test=1,
        derived_pairs=4,
        derived_test=1,
        train_sessions=3,
        test_sessions=1,
    ),
    "standard": Preset(
        "standard",
        25,
        25,
        5,
        5,
        3,
        poses=10,
        test_poses=2,
        train_pairs=20_000,
        test_pairs=150,
        triples=1_000,
        cloud_parts=100,
        chunk=64,
        retrieval_pairs=1_000,
        overlap_pairs=2_500,
        overlap_test=30,
        derived_pairs=1_500,
        derived_test=30,
        train_sessions=250,
        test_sessions=40,
    ),
    "large": Preset(
        "large",
        100,
        100,
        10,
        10,
        5,
        poses=12,
        test_poses=2,
        train_pairs=100_000,
        test_pairs=500,
        triples=5_000,
        cloud_parts=500,
        chunk=128,
        retrieval_pairs=10_000,
        overlap_pairs=12_000,
        overlap_test=100,
        derived_pairs=7_500,
        derived_test=100,
        train_sessions=1_200,
        test_sessions=150,
    ),
}


@dataclass(frozen=True)
class ShapeGroup:
    """Identities that share a label and split role, e.g. the unknown women."""

    name: str  # known_man, known_woman, unknown_man, unknown_woman, child
    count: int


class ShapeSource(Protocol):
    """Where posed bodies come from: anny in a real build, a synthetic body in tests."""

    description: str  # recorded with the template

    def template(self) -> Template: ...

    def shapes(self, groups: Sequence[ShapeGroup], poses: int, seed: int) -> tuple[np.ndarray, list[dict]]:
        """(identities, poses, n, 3) capped-body vertices and one metadata dict per identity."""
        ...


@dataclass
class Layout:
    """Files of a data set directory."""

    root: Path
    work: Path = field(init=False)

    def __post_init__(self) -> None:
        self.work = self.root / "work"

    def chunk(self, stage: str, index: int) -> Path:
        return self.work / f"{stage}-{index:05d}.npz"


def groups_of(preset: Preset) -> list[ShapeGroup]:
    return [
        ShapeGroup("known_man", preset.known_men),
        ShapeGroup("known_woman", preset.known_women),
        ShapeGroup("unknown_man", preset.unknown_men),
        ShapeGroup("unknown_woman", preset.unknown_women),
        ShapeGroup("child", preset.children),
    ]


# --- workers (top-level and path-addressed, so process pools and Dask can ship them) ---------
# Each worker is one process per core, so its BLAS must not start a thread per core too: with
# OpenBLAS's default, two workers on two cores drew masks 3x slower (measured, 3.9 → 1.3 s a
# chunk) and solved spectra 12 % slower.
@lru_cache(maxsize=2)
def _sampler(template_dir: str) -> RegionSampler:
    return RegionSampler(Template.load(Path(template_dir)))


@lru_cache(maxsize=2)
def _mapped(path: str) -> np.ndarray:
    """A saved array, memory-mapped once per worker process."""
    return np.load(path, mmap_mode="r")


@threadpool_limits.wrap(limits=1)
def draw_masks(template_dir: str, seed: int, chunk: int, kind: str, count: int) -> dict[str, np.ndarray]:
    """``count`` pairs (alternating scenarios) or triples, packed, from seed (seed, chunk)."""
    sampler = _sampler(template_dir)
    rng = np.random.default_rng([seed, chunk, MASK_STREAMS[kind]])
    rows: list[list[np.ndarray]] = []
    scenarios = []
    for i in range(count):
        if kind == "triple":
            first, second = sample_triple(sampler, rng)
            rows.append([first.a, first.b, second.b, first.union, second.union])
            scenarios.append(PARTIAL_UNION)
        else:
            scenario = {
                "pair": (FULL_COVERAGE, PARTIAL_UNION)[(chunk + i) % 2],
                "candidate": PARTIAL_UNION,
                "retrieval": FULL_COVERAGE,
                "overlap": OVERLAP,
            }[kind]
            pair = sample_pair(sampler, rng, scenario)
            rows.append([pair.a, pair.b, pair.union])
            scenarios.append(scenario)
    return {"masks": np.packbits(np.array(rows), axis=-1), "scenario": np.array(scenarios)}


@threadpool_limits.wrap(limits=1)
def draw_sessions(template_dir: str, shapes_path: str, seed: int, chunk: int, shapes: np.ndarray) -> dict:
    """A scanning session around each of ``shapes``, packed (count, views, bytes), from seed (seed, chunk)."""
    sampler = _sampler(template_dir)
    bodies = _mapped(shapes_path)
    rng = np.random.default_rng([seed, chunk, 9])
    n = len(sampler.template.vertices)
    masks = np.zeros((len(shapes), SESSION_VIEWS, (n + 7) // 8), np.uint8)
    ok = np.zeros(len(shapes), bool)
    for row, shape in enumerate(shapes):
        session = scan_session(sampler, np.asarray(bodies[shape], dtype=np.float64), rng)
        if session is not None:
            masks[row] = np.packbits([*session.orbit, session.rescan, session.close_up], axis=-1)
            ok[row] = True
    return {"masks": masks, "ok": ok}


@threadpool_limits.wrap(limits=1)
def solve_chunk(
    template_dir: str, shapes_path: str, masks_path: str, tasks: np.ndarray, variants: np.ndarray, k: int
) -> np.ndarray:
    """Spectra (len(tasks), k) of (shape, mask) rows of ``tasks`` in their variants."""
    template = Template.load(Path(template_dir))
    shapes = _mapped(shapes_path)
    packed = _mapped(masks_path)
    n = len(template.vertices)
    out = np.empty((len(tasks), k))
    for row, ((shape, mask), variant) in enumerate(zip(tasks, variants, strict=True)):
        region = np.unpackbits(packed[mask], count=n).astype(bool)
        out[row] = task_spectrum(np.asarray(shapes[shape], dtype=np.float64), template.faces, region, str(variant), k)
    return out


# --- the build -------------------------------------------------------------------------------
def run_tasks(
    function: Callable,
    argument_lists: list[tuple],
    done: Callable[[int, object], None],
    scheduler: str | None,
    workers: int | None,
    label: str,
) -> None:
    """Run ``function(*arguments)`` for each item, calling ``done(index, result)`` as they finish."""
    if not argument_lists:
        return
    progress = tqdm(total=len(argument_lists), desc=label, unit="chunk")
    if scheduler:
        from distributed import Client
        from distributed import as_completed as dask_completed

        with Client(scheduler) as client:
            futures = {client.submit(function, *args, pure=False): i for i, args in enumerate(argument_lists)}
            for future in dask_completed(futures):
                done(futures[future], future.result())
                progress.update()
    else:
        with ProcessPoolExecutor(max_workers=workers) as pool:
            futures = {pool.submit(function, *args): i for i, args in enumerate(argument_lists)}
            for future in as_completed(futures):
                done(futures[future], future.result())
                progress.update()
    progress.close()


def build_dataset(
    source: ShapeSource,
    preset: Preset,
    out: Path,
    seed: int = 0,
    scheduler: str | None = None,
    workers: int | None = None,
) -> dict:
    """Build (or resume) the data set of ``preset`` in ``out``; returns its manifest."""
    started = time.perf_counter()
    layout = Layout(out)
    layout.work.mkdir(parents=True, exist_ok=True)
    template_dir = out / "template"
    if not (template_dir / "template.npz").exists():
        source.template().save(template_dir, source.description)
    sampler = _sampler(str(template_dir))
    shapes_path, identities = _stage_shapes(source, preset, layout, seed)
    pairs, triples = _stage_masks(preset, layout, str(template_dir), seed, scheduler, workers)
    sessions = _stage_sessions(
        preset, layout, identities, str(template_dir), str(shapes_path), seed, scheduler, workers
    )
    table, masks = _stage_splits(preset, identities, pairs, triples, sessions, sampler, seed)
    masks_path = layout.work / "masks.npy"
    np.save(masks_path, masks)
    spectra = _stage_spectra(
        preset, layout, table, str(template_dir), str(shapes_path), str(masks_path), scheduler, workers
    )
    manifest = _write(out, preset, seed, identities, table, masks, spectra, time.perf_counter() - started)
    export_samples(out, dict(np.load(out / "dataset.npz")), np.load(shapes_path, mmap_mode="r"), sampler.template.faces)
    return manifest


def _stage_shapes(source: ShapeSource, preset: Preset, layout: Layout, seed: int) -> tuple[Path, list[dict]]:
    path, meta = layout.work / "shapes.npy", layout.work / "identities.json"
    if not path.exists():
        shapes, identities = source.shapes(groups_of(preset), preset.poses, seed)
        flat = shapes.reshape(-1, *shapes.shape[2:]).astype(np.float32)
        np.save(path, flat)
        meta.write_text(json.dumps(identities, indent=1))
    return path, json.loads(meta.read_text())


def _stage_masks(
    preset: Preset, layout: Layout, template_dir: str, seed: int, scheduler: str | None, workers: int | None
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Pairs for training and Test A, candidates for Test B, and triples, in resumable chunks."""
    test_groups = 5
    plan = {
        "pair": preset.train_pairs + test_groups * preset.test_pairs,
        "candidate": test_groups * preset.test_pairs * 4,  # Test B picks its union types here
        "triple": preset.triples,
        "retrieval": preset.retrieval_pairs,
        "overlap": preset.overlap_pairs + test_groups * preset.overlap_test,
    }
    results: dict[str, dict[str, np.ndarray]] = {}
    for kind, total in plan.items():
        counts = [min(preset.chunk, total - start) for start in range(0, total, preset.chunk)]
        missing = [i for i in range(len(counts)) if _chunk_rows(layout.chunk(kind, i)) < counts[i]]

        def save(index: int, result: dict, kind: str = kind, missing: list[int] = missing) -> None:
            np.savez(layout.chunk(kind, missing[index]), **result)

        run_tasks(
            draw_masks,
            [(template_dir, seed, i, kind, counts[i]) for i in missing],
            save,
            scheduler,
            workers,
            f"masks ({kind})",
        )
        # A chunk's draws are a prefix of one stream: a chunk saved by a preset that drew more
        # from it holds this preset's draws first.
        parts = [np.load(layout.chunk(kind, i)) for i in range(len(counts))]
        results[kind] = {
            key: np.concatenate([p[key][:count] for p, count in zip(parts, counts, strict=True)])
            for key in ("masks", "scenario")
        }
    return {kind: results[kind] for kind in ("pair", "candidate", "retrieval", "overlap")}, results["triple"]


def _stage_sessions(
    preset: Preset,
    layout: Layout,
    identities: list[dict],
    template_dir: str,
    shapes_path: str,
    seed: int,
    scheduler: str | None,
    workers: int | None,
) -> dict[str, np.ndarray]:
    """Scanning sessions on training bodies (known identities, training poses) and on Test C's
    (identities never trained on, any pose), in resumable chunks."""
    rng = np.random.default_rng([seed, 8])
    plan: list[tuple[int, str, str]] = []
    for split, groups, count in (("train", ("known_man", "known_woman"), preset.train_sessions),) + tuple(
        ("test_c", (group,), preset.test_sessions) for group in TEST_C_GROUPS
    ):
        for _ in range(count):
            group = str(rng.choice(groups))
            identity = int(rng.choice([i for i, m in enumerate(identities) if m["group"] == group]))
            pose = int(rng.choice(poses_for(split, group, preset.poses, preset.test_poses)))
            plan.append((identity * preset.poses + pose, split, group))
    shapes = np.array([p[0] for p in plan], dtype=np.int64)
    starts = list(range(0, len(plan), preset.chunk))
    missing = [i for i in range(len(starts)) if not layout.chunk("session", i).exists()]

    def save(index: int, result: dict) -> None:
        np.savez(layout.chunk("session", missing[index]), **result)

    arguments = [(template_dir, shapes_path, seed, i, shapes[starts[i] : starts[i] + preset.chunk]) for i in missing]
    run_tasks(draw_sessions, arguments, save, scheduler, workers, "sessions")
    parts = [np.load(layout.chunk("session", i)) for i in range(len(starts))]
    return {
        "masks": np.concatenate([p["masks"] for p in parts]) if parts else np.zeros((0, SESSION_VIEWS, 0), np.uint8),
        "ok": np.concatenate([p["ok"] for p in parts]) if parts else np.zeros(0, bool),
        "shape": shapes,
        "split": np.array([p[1] for p in plan]),
        "group": np.array([p[2] for p in plan]),
    }


def _chunk_rows(path: Path) -> int:
    """Draws saved in a mask chunk; 0 for none yet."""
    if not path.exists():
        return 0
    with np.load(path) as chunk:
        return len(chunk["scenario"])


def _stage_splits(
    preset: Preset,
    identities: list[dict],
    pairs: dict,
    triples: dict,
    sessions: dict,
    sampler: RegionSampler,
    seed: int,
) -> tuple[dict[str, np.ndarray], np.ndarray]:
    """Assign pairs to shapes and splits; Test B realizes held-out union types with new pairs."""
    rng = np.random.default_rng([seed, 2])
    template = sampler.template
    n = len(template.vertices)
    writer = Rows([np.packbits(np.ones(n, bool))])  # mask 0: the whole body
    add_mask = writer.mask

    def add(split: str, group: str, scenario: str, packed: np.ndarray, draw: np.random.Generator = rng) -> None:
        identity = int(draw.choice([i for i, m in enumerate(identities) if m["group"] == group]))
        pose_pool = poses_for(split, group, preset.poses, preset.test_poses)
        pose_a = int(draw.choice(pose_pool))
        pose_b = pose_a if draw.random() < 0.5 else int(draw.choice(pose_pool))
        a, b = add_mask(packed[0]), add_mask(packed[1])
        union = 0 if scenario == FULL_COVERAGE else add_mask(packed[2])
        shapes = (identity * preset.poses + pose_a, identity * preset.poses + pose_b)
        writer.put(split, group, scenario, MESH, shapes, (a, b, union))

    test_groups = ["known_man", "known_woman", "unknown_man", "unknown_woman", "child"]
    pair_masks, pair_scenarios = pairs["pair"]["masks"], pairs["pair"]["scenario"]
    for i in range(preset.train_pairs):
        add("train", str(rng.choice(["known_man", "known_woman"])), str(pair_scenarios[i]), pair_masks[i])
    offset = preset.train_pairs
    for g, group in enumerate(test_groups):
        for j in range(preset.test_pairs):
            i = offset + g * preset.test_pairs + j
            add("test_a", group, str(pair_scenarios[i]), pair_masks[i])
    seen = np.concatenate(
        [pair_masks[: preset.train_pairs][pair_scenarios[: preset.train_pairs] == PARTIAL_UNION, 2]]
        + [triples["masks"][:, column] for column in (3, 4)]
    )
    held_out = _held_out_unions(_unpack(pairs["candidate"]["masks"][:, 2], n), _unpack(seen, n), sampler)
    test_b_rng = np.random.default_rng([seed, 3])  # Test B draws leave every other row as it was
    for group in test_groups:
        for pair in _realizations(sampler, held_out, preset.test_pairs, test_b_rng):
            add("test_b", group, PARTIAL_UNION, np.packbits([pair.a, pair.b, pair.union], axis=-1), test_b_rng)
    table = _with_variants(writer.take(), preset, rng)
    table["triples"] = _triple_rows(triples, preset, identities, rng, add_mask)
    # Appended last, from their own streams: the rows above stay as they were without them.
    retrieval_rng = np.random.default_rng([seed, 4])
    for i, packed in enumerate(pairs["retrieval"]["masks"]):
        add("retrieval", test_groups[i % len(test_groups)], FULL_COVERAGE, packed, retrieval_rng)
    table = _appended(table, writer.take())
    overlap_rng = np.random.default_rng([seed, 5])
    overlap_masks = pairs["overlap"]["masks"]
    for i in range(preset.overlap_pairs):
        add("train", str(overlap_rng.choice(["known_man", "known_woman"])), OVERLAP, overlap_masks[i], overlap_rng)
    for g, group in enumerate(test_groups):
        for packed in overlap_masks[preset.overlap_pairs + g * preset.overlap_test :][: preset.overlap_test]:
            add("test_a", group, OVERLAP, packed, overlap_rng)
    poses = (preset.poses, preset.test_poses)
    counts = {"train": preset.derived_pairs, "test_a": preset.derived_test}
    derived_rows(writer, table, poses, counts, np.random.default_rng([seed, 6]))
    chains = session_rows(writer, sampler, sessions, poses, np.random.default_rng([seed, 7]))
    extension = writer.take()
    table = _appended(table, _remeshed_copies(extension))
    table["triples"] = np.concatenate([table["triples"], chains.triples])
    table["chains"] = chains.test
    return table, np.array(writer.masks)


def _appended(table: dict[str, np.ndarray], rows: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """``table`` with ``rows`` (same columns) after its own; the other tables of it kept."""
    if not len(rows["split"]):
        return table
    return {key: np.concatenate([value, rows[key]]) if key in rows else value for key, value in table.items()}


def _unpack(packed: np.ndarray, n: int) -> np.ndarray:
    return np.unpackbits(packed, axis=-1, count=n).astype(bool).reshape(-1, n)


def _held_out_unions(candidates: np.ndarray, seen: np.ndarray, sampler: RegionSampler) -> list[np.ndarray]:
    """Union types for Test B: candidate unions unlike every seen union and unlike each other.

    "Unlike" is a symmetric IoU below ``TEST_B_MAX_IOU``. Training draws tens of thousands of
    fresh unions, which leaves few such candidates: the paper's Test B likewise has a handful
    of union types, each met in many poses, identities and part pairs.
    """
    weights, mirror = sampler.vertex_area, sampler.template.mirror
    novelty = symmetric_iou(candidates, seen, weights, mirror)
    chosen: list[np.ndarray] = []
    for i in np.flatnonzero(novelty < TEST_B_MAX_IOU):
        if len(chosen) == TEST_B_TYPES:
            break
        if not chosen or symmetric_iou(candidates[i : i + 1], np.array(chosen), weights, mirror)[0] < TEST_B_MAX_IOU:
            chosen.append(candidates[i])
    return chosen


def _realizations(sampler: RegionSampler, unions: list[np.ndarray], count: int, rng: np.random.Generator) -> list[Pair]:
    """Up to ``count`` pairs, cycling through ``unions``; a union that resists splitting gets fewer."""
    pairs: list[Pair] = []
    for attempt in range(count * SPLIT_ATTEMPTS if unions else 0):
        if len(pairs) == count:
            break
        pair = split_union(sampler, unions[attempt % len(unions)], rng)
        if pair is not None:
            pairs.append(pair)
    return pairs


def _with_variants(table: dict[str, np.ndarray], preset: Preset, rng: np.random.Generator) -> dict[str, np.ndarray]:
    """Every test row again re-meshed, and some as point clouds (parts only; unions stay meshes)."""
    test = np.flatnonzero(table["split"] != "train")
    clouds = rng.choice(test, size=min(preset.cloud_parts, len(test)), replace=False)
    return _copies(_copies(table, test, REMESHED), np.sort(clouds), CLOUD, table)


def _remeshed_copies(table: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """Every test row again with both parts re-meshed (the union stays the mesh's)."""
    return _copies(table, np.flatnonzero(table["split"] != "train"), REMESHED)


def _copies(
    table: dict[str, np.ndarray], rows: np.ndarray, variant: str, source: dict[str, np.ndarray] | None = None
) -> dict[str, np.ndarray]:
    """``table`` followed by ``rows`` of ``source`` (default: of ``table``) in ``variant``."""
    source = table if source is None else source
    return {
        key: np.concatenate([value, np.full(len(rows), variant) if key == "variant" else source[key][rows]])
        for key, value in table.items()
    }


def _triple_rows(
    triples: dict,
    preset: Preset,
    identities: list[dict],
    rng: np.random.Generator,
    add_mask: Callable[[np.ndarray], int],
) -> np.ndarray:
    """(t, 7): split flag (0 train, 1 test), shape, masks a, b, c, a∪b, a∪b∪c."""
    known = [i for i, m in enumerate(identities) if m["group"].startswith("known")]
    rows = []
    for packed in triples["masks"]:
        test = rng.random() < 0.15
        identity = int(rng.choice(known))
        pose = int(rng.choice(poses_for("test_a" if test else "train", "known_man", preset.poses, preset.test_poses)))
        rows.append([int(test), identity * preset.poses + pose, *[add_mask(m) for m in packed]])
    return np.array(rows, dtype=np.int64).reshape(-1, 7)


def _spectrum_tasks(table: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct (shape, mask, variant) tasks and, per table cell, the task it reads."""
    triples = table["triples"]
    parts_variant = table["variant"]
    cells = [
        (table["shape_a"], table["mask_a"], parts_variant),
        (table["shape_b"], table["mask_b"], parts_variant),
        (table["shape_a"], table["mask_union"], np.full(len(parts_variant), MESH)),
    ] + [(triples[:, 1], triples[:, column], np.full(len(triples), MESH)) for column in range(2, 7)]
    chains = table["chains"]
    cells += [(chains[:, 0], chains[:, column], np.full(len(chains), MESH)) for column in range(1, CHAIN_COLUMNS)]
    shapes = np.concatenate([c[0] for c in cells])
    masks = np.concatenate([c[1] for c in cells])
    variants = np.concatenate([c[2] for c in cells]).astype(str)
    names = np.array(sorted(VARIANTS))
    code = np.searchsorted(names, variants)
    keys = np.stack([shapes, masks, code], axis=1)
    unique, inverse = np.unique(keys, axis=0, return_inverse=True)
    return unique, names[unique[:, 2]], inverse.reshape(-1)


def _stage_spectra(
    preset: Preset,
    layout: Layout,
    table: dict,
    template_dir: str,
    shapes_path: str,
    masks_path: str,
    scheduler: str | None,
    workers: int | None,
) -> dict[str, np.ndarray]:
    tasks, variants, cell_task = _spectrum_tasks(table)
    keys = _task_keys(tasks, variants, np.load(masks_path, mmap_mode="r"))
    cached = _cached_spectra(layout)
    todo = np.flatnonzero([key not in cached for key in keys])
    chunks = list(_chunks(todo, preset.chunk))
    first = 1 + max((int(path.stem.split("-")[1]) for path in layout.work.glob("spectra-*.npz")), default=-1)

    def save(index: int, values: np.ndarray) -> None:
        np.savez(layout.chunk("spectra", first + index), keys=keys[chunks[index]], values=values)
        cached.update(zip(keys[chunks[index]], values, strict=True))

    arguments = [(template_dir, shapes_path, masks_path, tasks[c, :2], variants[c], preset.k) for c in chunks]
    run_tasks(solve_chunk, arguments, save, scheduler, workers, "spectra")
    values = np.array([cached[key] for key in keys]).reshape(len(keys), preset.k)
    return {"values": values, "shape": tasks[:, 0], "mask": tasks[:, 1], "variant": variants, "cell_task": cell_task}


def _task_keys(tasks: np.ndarray, variants: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """A content key per (shape, mask, variant) task.

    Spectra are cached by what they are the spectrum of, not by their place in the task list,
    so a build whose splits changed still reuses every spectrum it computed before.
    """
    keys = [
        hashlib.blake2b(
            np.int64(shape).tobytes() + masks[mask].tobytes() + str(variant).encode(), digest_size=16
        ).digest()
        for (shape, mask, _), variant in zip(tasks, variants, strict=True)
    ]
    return np.array(keys, dtype="S16")


def _cached_spectra(layout: Layout) -> dict[bytes, np.ndarray]:
    cached: dict[bytes, np.ndarray] = {}
    for path in sorted(layout.work.glob("spectra-*.npz")):
        with np.load(path) as chunk:
            cached.update(zip(chunk["keys"], chunk["values"], strict=True))
    return cached


def _chunks(items: Iterable[int], size: int) -> Iterable[np.ndarray]:
    items = np.asarray(list(items))
    for start in range(0, len(items), size):
        yield items[start : start + size]


def _write(
    out: Path,
    preset: Preset,
    seed: int,
    identities: list[dict],
    table: dict,
    masks: np.ndarray,
    spectra: dict,
    seconds: float,
) -> dict:
    """``dataset.npz`` with every table, ``manifest.json`` and ``DATASET_CARD.md``."""
    n_rows = len(table["split"])
    n_triples = len(table["triples"])
    cell = spectra["cell_task"]
    columns = {
        "spec_a": cell[:n_rows],
        "spec_b": cell[n_rows : 2 * n_rows],
        "spec_union": cell[2 * n_rows : 3 * n_rows],
    }
    triple_spectra = cell[3 * n_rows : 3 * n_rows + 5 * n_triples].reshape(5, n_triples).T
    n_chains = len(table["chains"])
    chain_spectra = cell[3 * n_rows + 5 * n_triples :].reshape(CHAIN_COLUMNS - 1, n_chains).T
    np.savez_compressed(
        out / "dataset.npz",
        masks=masks,
        spectra=spectra["values"],
        spectrum_shape=spectra["shape"],
        spectrum_mask=spectra["mask"],
        spectrum_variant=spectra["variant"],
        triples=table["triples"],
        triple_spectra=triple_spectra,
        chains=table["chains"],
        chain_spectra=chain_spectra,
        **{key: value for key, value in table.items() if key not in ("triples", "chains")},
        **columns,
    )
    failed = int(np.isnan(spectra["values"]).any(axis=1).sum())
    counts: dict[str, int] = {}
    for split, group, variant in zip(table["split"], table["group"], table["variant"], strict=True):
        key = f"{split}/{group}/{variant}"
        counts[key] = counts.get(key, 0) + 1
    manifest = {
        "preset": asdict(preset),
        "seed": seed,
        "identities": len(identities),
        "shapes": len(identities) * preset.poses,
        "rows": n_rows,
        "triples": n_triples,
        "test_c_chains": n_chains,
        "distinct_masks": len(masks),
        "test_b_union_types": len(np.unique(masks[table["mask_union"][table["split"] == "test_b"]], axis=0)),
        "spectra": len(spectra["values"]),
        "failed_spectra": failed,
        "counts": dict(sorted(counts.items())),
        "build_seconds": round(seconds, 1),
        "bytes": (out / "dataset.npz").stat().st_size,
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    (out / "DATASET_CARD.md").write_text(_card(manifest))
    return manifest


def _card(manifest: dict) -> str:
    preset = manifest["preset"]
    lines = [
        f"# Data set card: preset `{preset['name']}`, seed {manifest['seed']}",
        "",
        f"- identities: {manifest['identities']} ({preset['known_men']} known men, {preset['known_women']} known "
        f"women, {preset['unknown_men']} unknown men, {preset['unknown_women']} unknown women, "
        f"{preset['children']} children) × {preset['poses']} poses = {manifest['shapes']} shapes",
        f"- pair rows: {manifest['rows']}; triples: {manifest['triples']}; "
        f"distinct masks: {manifest['distinct_masks']}",
        f"- Test B: {manifest['test_b_union_types']} held-out union types, each realized by different part pairs",
        f"- spectra: {manifest['spectra']} (k = {preset['k']}), failed: {manifest['failed_spectra']}",
        f"- size: {manifest['bytes'] / 1e6:.1f} MB (`dataset.npz`); build time: {manifest['build_seconds']} s "
        "(of this run: a resumed build reuses finished chunks and counts only its own work)",
        "",
        "| split/group/variant | rows |",
        "|---|---|",
        *[f"| {key} | {value} |" for key, value in manifest["counts"].items()],
        "",
    ]
    return "\n".join(lines)
