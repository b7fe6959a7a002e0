"""The decoder's data: many anny bodies, each its rest-pose vertices and its posed spectra.

A spectrum of a complete body determines its shape up to pose (isometry), so the decoder learns
from the spectra of every identity in several poses (rest and random valid poses) to one target,
the identity's rest-pose vertices on the template's topology. Identities are drawn from anny's
calibrated distribution with their own seed stream, never the benchmark data set's, so the data
set's unknown identities stay unknown to the decoder too. Built on a process pool, one body per
task, deterministic from the seed.
"""

import json
import multiprocessing
import time
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
from threadpoolctl import threadpool_limits
from tqdm import tqdm

from app.geometry import Mesh, SpectrumOptions, mesh_spectrum
from training.data.bodies import BodyModel, Identity

BODIES_FILE = "bodies.npz"
SEED_OFFSET = 7_000  # identity streams far from the data set's (seed · 100 + group number)


@dataclass(frozen=True)
class BodiesPreset:
    """How many identities of each label, and how many poses each (the rest pose first)."""

    men: int
    women: int
    children: int
    poses: int
    k: int = 20


BODIES_PRESETS = {
    "tiny": BodiesPreset(men=6, women=6, children=4, poses=2),
    # ~0.35 s a body-pose on one core (collision test, posing, a k = 20 solve on 12 k vertices).
    "standard": BodiesPreset(men=500, women=500, children=250, poses=3),
}


@lru_cache(maxsize=1)
def _body() -> BodyModel:
    return BodyModel()


@threadpool_limits.wrap(limits=1)
def _one_body(phenotype: dict[str, float], label: str, seed: tuple[int, ...], poses: int, k: int) -> dict:
    """Rest-pose vertices and the complete spectrum in each of ``poses`` valid poses."""
    body = _body()
    identity = Identity(phenotype, label, label)
    chosen = body.valid_poses(identity, np.random.default_rng(seed), poses, rest_first=True)
    posed = body.pose(identity, chosen)
    spectra = [
        mesh_spectrum(Mesh(v.astype(np.float64), body.topology.faces), SpectrumOptions(k=k)).eigenvalues for v in posed
    ]
    return {"rest": posed[0].astype(np.float32), "spectra": np.asarray(spectra, np.float64)}


def sample_identities(preset: BodiesPreset, seed: int) -> list[Identity]:
    body = _body()
    identities = []
    for number, (label, count) in enumerate((("man", preset.men), ("woman", preset.women), ("child", preset.children))):
        identities += body.sample_identities(SEED_OFFSET + seed * 10 + number, label, label, count)
    return identities


def build_bodies(preset: BodiesPreset, out: Path, seed: int = 0, workers: int | None = None) -> dict:
    """Write ``bodies.npz`` (rest vertices, spectra, labels, phenotypes) and a manifest."""
    started = time.perf_counter()
    identities = sample_identities(preset, seed)
    out.mkdir(parents=True, exist_ok=True)
    # Spawned, not forked: anny's torch and warp are loaded in this process, and a forked child
    # inherits their threads' locks held (the pool hung at the first body).
    with ProcessPoolExecutor(workers, mp_context=multiprocessing.get_context("spawn")) as pool:
        futures = [
            pool.submit(_one_body, i.phenotype, i.label, (SEED_OFFSET, seed, n), preset.poses, preset.k)
            for n, i in enumerate(identities)
        ]
        results = [f.result() for f in tqdm(futures, desc="bodies", unit="body")]
    names = sorted(identities[0].phenotype)
    np.savez_compressed(
        out / BODIES_FILE,
        rest=np.stack([r["rest"] for r in results]),
        spectra=np.stack([r["spectra"] for r in results]),
        label=np.array([i.label for i in identities]),
        phenotype=np.array([[i.phenotype[name] for name in names] for i in identities]),
        phenotype_names=np.array(names),
    )
    manifest = {
        "preset": asdict(preset),
        "seed": seed,
        "identities": len(identities),
        "seconds": round(time.perf_counter() - started, 1),
    }
    (out / "manifest.json").write_text(json.dumps(manifest, indent=1))
    return manifest
