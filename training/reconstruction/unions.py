"""Pairs of parts that cover each body of the bodies build, for the decoder's union rows.

The decoder must read the union operator's predictions, errors included, for people it never
saw; the benchmark's full-coverage pairs come from its 45 training identities only, which
teaches the decoder those people more than the operator's error (model card). So every body of
the bodies build also gets one random full-coverage pair (the benchmark's own generator on the
template), cut from its rest-pose body and solved by ``app.geometry``. The operator never saw
these bodies, so its predictions of them are a new person's, with no memory rows to hide.
"""

import multiprocessing
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from training.data.pairs import FULL_COVERAGE, sample_pair
from training.data.spectra import MESH, task_spectrum
from training.data.workers import mapped, sampler_of
from training.reconstruction.bodies import BODIES_FILE, SEED_OFFSET

UNIONS_FILE = "unions.npz"
REST_FILE = "rest.npy"  # the rest-pose bodies uncompressed, memory-mapped by the workers


@threadpool_limits.wrap(limits=1)
def _pair_spectra(template_dir: str, rest_path: str, seed: int, k: int, body: int) -> np.ndarray:
    """(2, k) the spectra of a full-coverage pair of parts of one rest-pose body."""
    sampler = sampler_of(template_dir)
    rng = np.random.default_rng([SEED_OFFSET, seed, body, 1])  # the body's poses use [SEED_OFFSET, seed, body]
    pair = sample_pair(sampler, rng, FULL_COVERAGE)
    rest = np.asarray(mapped(rest_path)[body], dtype=np.float64)
    return np.stack([task_spectrum(rest, sampler.template.faces, mask, MESH, k) for mask in (pair.a, pair.b)])


def build_body_unions(bodies_dir: Path, template_dir: Path, seed: int = 0, workers: int | None = None) -> Path:
    """Write ``unions.npz``: parts ``a``, ``b`` (n, k) of one pair per body, and ``body`` (n,)."""
    arrays = np.load(bodies_dir / BODIES_FILE)
    rest = arrays["rest"]  # decompressed once
    rest_path = bodies_dir / REST_FILE
    np.save(rest_path, rest)
    k = arrays["spectra"].shape[2]
    bodies = np.arange(len(rest))
    context = multiprocessing.get_context("spawn")  # no torch state inherited (see bodies.py)
    with ProcessPoolExecutor(workers, mp_context=context) as pool:
        jobs = [pool.submit(_pair_spectra, str(template_dir), str(rest_path), seed, k, int(b)) for b in bodies]
        spectra = np.stack([job.result() for job in tqdm(jobs, desc="pairs", unit="pair")])
    rest_path.unlink()
    solved = np.isfinite(spectra).all(axis=(1, 2))
    out = bodies_dir / UNIONS_FILE
    np.savez_compressed(out, a=spectra[solved, 0], b=spectra[solved, 1], body=bodies[solved])
    return out
