"""Parts and scans cut from each body of the bodies build, for the decoder's extra rows.

The benchmark's rows come from its 45 training identities only, which teaches the decoder
those people more than what it should learn (model card). So every body of the bodies build
(1 250 people the union operator never saw) can also give, cut from its rest-pose body on the
template's topology and solved by ``app.geometry`` as the data build solves a part:

- one random full-coverage pair of parts (``unions.npz``, ``build-bodies --pairs``), whose
  predicted union is a new person's, with no memory rows to hide;
- its scans (``scans.npz``, ``build-bodies --scans``): the whole body with blind spots
  (:mod:`training.reconstruction.blind_spots`) and partial unions covering
  ``PARTIAL_COVERAGE`` of it or more, short of all: what one scan or a session not yet closed
  gives, for 1 125 training people instead of 45.
"""

import multiprocessing
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from training.data.pairs import FULL_COVERAGE, PARTIAL_UNION, sample_pair
from training.data.spectra import MESH, task_spectrum
from training.data.workers import mapped, sampler_of
from training.reconstruction.blind_spots import blind_spot_mask
from training.reconstruction.bodies import BODIES_FILE, SEED_OFFSET

UNIONS_FILE = "unions.npz"
SCANS_FILE = "scans.npz"
REST_FILE = "rest.npy"  # the rest-pose bodies uncompressed, memory-mapped by the workers
PARTIAL_COVERAGE = 0.5  # of the body's area: a union covering less says too little of the person
BLIND_SPOT, PARTIAL = "blind_spot", "partial"
SCAN_KINDS = (BLIND_SPOT, BLIND_SPOT, BLIND_SPOT, PARTIAL, PARTIAL, PARTIAL)  # each body's scans, in order


@threadpool_limits.wrap(limits=1)
def _pair_spectra(template_dir: str, rest_path: str, seed: int, k: int, body: int) -> np.ndarray:
    """(2, k) the spectra of a full-coverage pair of parts of one rest-pose body."""
    sampler = sampler_of(template_dir)
    rng = np.random.default_rng([SEED_OFFSET, seed, body, 1])  # the body's poses use [SEED_OFFSET, seed, body]
    pair = sample_pair(sampler, rng, FULL_COVERAGE)
    rest = np.asarray(mapped(rest_path)[body], dtype=np.float64)
    return np.stack([task_spectrum(rest, sampler.template.faces, mask, MESH, k) for mask in (pair.a, pair.b)])


@threadpool_limits.wrap(limits=1)
def scan_spectra(template_dir: str, rest_path: str, seed: int, k: int, body: int) -> np.ndarray:
    """(len(SCAN_KINDS), k) the spectra of one rest-pose body's scans."""
    sampler = sampler_of(template_dir)
    rng = np.random.default_rng([SEED_OFFSET, seed, body, 2])
    masks = []
    for kind in SCAN_KINDS:
        if kind == BLIND_SPOT:
            masks.append(blind_spot_mask(sampler.template.vertices, rng))
            continue
        while True:
            union = sample_pair(sampler, rng, PARTIAL_UNION).union
            if sampler.area_fraction(union) >= PARTIAL_COVERAGE:
                masks.append(union)
                break
    rest = np.asarray(mapped(rest_path)[body], dtype=np.float64)
    return np.stack([task_spectrum(rest, sampler.template.faces, mask, MESH, k) for mask in masks])


def _over_rest_bodies(
    bodies_dir: Path, template_dir: Path, task: Callable[..., np.ndarray], seed: int, workers: int | None
) -> np.ndarray:
    """(bodies, …) ``task`` of every rest-pose body of the build, on a spawned process pool."""
    arrays = np.load(bodies_dir / BODIES_FILE)
    rest = arrays["rest"]  # decompressed once
    rest_path = bodies_dir / REST_FILE
    np.save(rest_path, rest)
    k = arrays["spectra"].shape[2]
    context = multiprocessing.get_context("spawn")  # no torch state inherited (see bodies.py)
    try:
        with ProcessPoolExecutor(workers, mp_context=context) as pool:
            jobs = [pool.submit(task, str(template_dir), str(rest_path), seed, k, body) for body in range(len(rest))]
            return np.stack([job.result() for job in tqdm(jobs, desc=task.__name__.strip("_"), unit="body")])
    finally:
        rest_path.unlink()


def build_body_unions(bodies_dir: Path, template_dir: Path, seed: int = 0, workers: int | None = None) -> Path:
    """Write ``unions.npz``: parts ``a``, ``b`` (n, k) of one pair per body, and ``body`` (n,)."""
    spectra = _over_rest_bodies(bodies_dir, template_dir, _pair_spectra, seed, workers)
    solved = np.isfinite(spectra).all(axis=(1, 2))
    out = bodies_dir / UNIONS_FILE
    np.savez_compressed(out, a=spectra[solved, 0], b=spectra[solved, 1], body=np.flatnonzero(solved))
    return out


def build_body_scans(bodies_dir: Path, template_dir: Path, seed: int = 0, workers: int | None = None) -> Path:
    """Write ``scans.npz``: ``spectra`` (m, k) of every body's scans, their ``body`` (m,) and
    ``kind`` (m,), one of SCAN_KINDS; scans that could not be solved left out."""
    spectra = _over_rest_bodies(bodies_dir, template_dir, scan_spectra, seed, workers)
    body = np.repeat(np.arange(len(spectra)), len(SCAN_KINDS))
    kind = np.tile(np.array(SCAN_KINDS), len(spectra))
    spectra = spectra.reshape(-1, spectra.shape[-1])
    solved = np.isfinite(spectra).all(axis=1)
    out = bodies_dir / SCANS_FILE
    np.savez_compressed(out, spectra=spectra[solved], body=body[solved], kind=kind[solved])
    return out
