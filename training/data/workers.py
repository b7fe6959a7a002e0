"""The build's parallel tasks and the runner that ships them to a process pool or a Dask cluster.

Workers are top-level functions addressed by paths (template folder, memory-mapped arrays), so
process pools and Dask can ship them. Each worker is one process per core, so its BLAS must not
start a thread per core too: with OpenBLAS's default, two workers on two cores drew masks 3×
slower (measured, 3.9 → 1.3 s a chunk) and solved spectra 12 % slower.
"""

from collections.abc import Callable, Iterable
from concurrent.futures import ProcessPoolExecutor, as_completed
from functools import lru_cache
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from training.data.camera import scan_session
from training.data.overlaps import SESSION_VIEWS
from training.data.pairs import FULL_COVERAGE, OVERLAP, PARTIAL_UNION, sample_pair, sample_triple
from training.data.regions import RegionSampler
from training.data.spectra import task_spectrum
from training.data.streams import chunk_stream
from training.data.template import Template


@lru_cache(maxsize=2)
def sampler_of(template_dir: str) -> RegionSampler:
    """The region sampler of a saved template, built once per process."""
    return RegionSampler(Template.load(Path(template_dir)))


@lru_cache(maxsize=2)
def mapped(path: str) -> np.ndarray:
    """A saved array, memory-mapped once per worker process."""
    return np.load(path, mmap_mode="r")


@threadpool_limits.wrap(limits=1)
def draw_masks(template_dir: str, seed: int, chunk: int, kind: str, count: int) -> dict[str, np.ndarray]:
    """``count`` pairs (alternating scenarios) or triples, packed, from the chunk's stream."""
    sampler = sampler_of(template_dir)
    rng = chunk_stream(seed, kind, chunk)
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
    """A scanning session around each of ``shapes``, packed (count, views, bytes), from the chunk's stream."""
    sampler = sampler_of(template_dir)
    bodies = mapped(shapes_path)
    rng = chunk_stream(seed, "session", chunk)
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
    shapes = mapped(shapes_path)
    packed = mapped(masks_path)
    n = len(template.vertices)
    out = np.empty((len(tasks), k))
    for row, ((shape, mask), variant) in enumerate(zip(tasks, variants, strict=True)):
        region = np.unpackbits(packed[mask], count=n).astype(bool)
        out[row] = task_spectrum(np.asarray(shapes[shape], dtype=np.float64), template.faces, region, str(variant), k)
    return out


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


def chunks(items: Iterable[int], size: int) -> Iterable[np.ndarray]:
    """``items`` in consecutive arrays of ``size`` (the last one shorter)."""
    items = np.asarray(list(items))
    for start in range(0, len(items), size):
        yield items[start : start + size]
