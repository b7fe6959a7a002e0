"""Build the benchmark: shapes, region pairs and triples, splits, spectra; resumable and parallel.

Stages, each saved under ``<out>/work`` before the next starts, so a killed build resumes
where it stopped: (1) posed shapes from a :class:`ShapeSource`; (2) masks of pairs and
triples, and scanning sessions, drawn in parallel chunks with per-chunk streams; (3) the
splits and the Test B filter (:mod:`training.data.splits`); (4) spectra of every distinct
(shape, mask, variant), in parallel chunks (:mod:`training.data.spectrum_cache`). The same
task functions (:mod:`training.data.workers`) run on a local process pool or, given a
scheduler address, on a Dask cluster. Everything is a function of the preset
(:mod:`training.data.presets`) and one seed (:mod:`training.data.streams`).
"""

import json
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Protocol

import numpy as np

from training.data.dataset_files import write_dataset
from training.data.overlaps import SESSION_VIEWS, TEST_C_GROUPS
from training.data.presets import GROUPS, TRAINING_GROUPS, Preset, ShapeGroup, groups_of
from training.data.rows import poses_for
from training.data.samples import export_samples
from training.data.spectrum_cache import cached_spectra, next_chunk_number, spectrum_tasks, task_keys
from training.data.splits import assign_rows
from training.data.streams import serial_stream
from training.data.template import Template
from training.data.workers import chunks, draw_masks, draw_sessions, run_tasks, sampler_of, solve_chunk


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


@dataclass(frozen=True)
class Runner:
    """Where the parallel stages run: a Dask scheduler's address, else a local pool of ``workers``."""

    scheduler: str | None = None
    workers: int | None = None


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
    runner = Runner(scheduler, workers)
    template_dir = out / "template"
    if not (template_dir / "template.npz").exists():
        source.template().save(template_dir, source.description)
    sampler = sampler_of(str(template_dir))
    shapes_path, identities = _stage_shapes(source, preset, layout, seed)
    pairs, triples = _stage_masks(preset, layout, str(template_dir), seed, runner)
    sessions = _stage_sessions(preset, layout, identities, str(template_dir), str(shapes_path), seed, runner)
    table, masks = assign_rows(preset, identities, pairs, triples, sessions, sampler, seed)
    masks_path = layout.work / "masks.npy"
    np.save(masks_path, masks)
    spectra = _stage_spectra(preset, layout, table, str(template_dir), str(shapes_path), str(masks_path), runner)
    manifest = write_dataset(out, preset, seed, identities, table, masks, spectra, time.perf_counter() - started)
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
    preset: Preset, layout: Layout, template_dir: str, seed: int, runner: Runner
) -> tuple[dict[str, np.ndarray], dict[str, np.ndarray]]:
    """Pairs for training and Test A, candidates for Test B, and triples, in resumable chunks."""
    plan = {
        "pair": preset.train_pairs + len(GROUPS) * preset.test_pairs,
        "candidate": len(GROUPS) * preset.test_pairs * 4,  # Test B picks its union types here
        "triple": preset.triples,
        "retrieval": preset.retrieval_pairs,
        "overlap": preset.overlap_pairs + len(GROUPS) * preset.overlap_test,
    }
    results: dict[str, dict[str, np.ndarray]] = {}
    for kind, total in plan.items():
        counts = [min(preset.chunk, total - start) for start in range(0, total, preset.chunk)]
        missing = [i for i in range(len(counts)) if _chunk_rows(layout.chunk(kind, i)) < counts[i]]

        def save(index: int, result: dict, kind: str = kind, missing: list[int] = missing) -> None:
            np.savez(layout.chunk(kind, missing[index]), **result)

        arguments = [(template_dir, seed, i, kind, counts[i]) for i in missing]
        run_tasks(draw_masks, arguments, save, runner.scheduler, runner.workers, f"masks ({kind})")
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
    runner: Runner,
) -> dict[str, np.ndarray]:
    """Scanning sessions on training bodies (known identities, training poses) and on Test C's
    (identities never trained on, any pose), in resumable chunks."""
    rng = serial_stream(seed, "session_plan")
    plan: list[tuple[int, str, str]] = []
    for split, groups, count in (("train", TRAINING_GROUPS, preset.train_sessions),) + tuple(
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
    run_tasks(draw_sessions, arguments, save, runner.scheduler, runner.workers, "sessions")
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


def _stage_spectra(
    preset: Preset,
    layout: Layout,
    table: dict,
    template_dir: str,
    shapes_path: str,
    masks_path: str,
    runner: Runner,
) -> dict[str, np.ndarray]:
    """The spectrum of every distinct task of ``table``, solving only those no earlier run saved."""
    tasks, variants, cell_task = spectrum_tasks(table)
    keys = task_keys(tasks, variants, np.load(masks_path, mmap_mode="r"))
    cached = cached_spectra(layout.work)
    todo = np.flatnonzero([key not in cached for key in keys])
    batches = list(chunks(todo, preset.chunk))
    first = next_chunk_number(layout.work)

    def save(index: int, values: np.ndarray) -> None:
        np.savez(layout.chunk("spectra", first + index), keys=keys[batches[index]], values=values)
        cached.update(zip(keys[batches[index]], values, strict=True))

    arguments = [(template_dir, shapes_path, masks_path, tasks[c, :2], variants[c], preset.k) for c in batches]
    run_tasks(solve_chunk, arguments, save, runner.scheduler, runner.workers, "spectra")
    values = np.array([cached[key] for key in keys]).reshape(len(keys), preset.k)
    return {"values": values, "shape": tasks[:, 0], "mask": tasks[:, 1], "variant": variants, "cell_task": cell_task}
