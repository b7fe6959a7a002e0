"""The seed ShapeDNA database and the retrieval evaluation (the paper's Table 4).

Every complete posed body of the benchmark gets its closed-surface spectrum (the data set's own
where it already has one). The service ships them as ``models/shapes.npz``. Retrieval is by
identity: a query is right at k when one of its k nearest stored shapes is the same person.
ShapeDNA queries each complete shape against the others; ours queries with the predicted union
of two partial scans, against every complete shape except the very shape the scans came from.
"""

import json
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

from app.retrieval import SEED_FILE, nearest_of
from training.common.data import PairTable, SpectralData
from training.data.pairs import FULL_COVERAGE
from training.data.spectra import MESH, task_spectrum

TOP = (1, 5, 10)


def _closed_spectrum(shapes_path: str, faces: np.ndarray, shape: int, k: int) -> np.ndarray:
    vertices = np.asarray(np.load(shapes_path, mmap_mode="r")[shape], dtype=np.float64)
    return task_spectrum(vertices, faces, np.ones(len(vertices), bool), MESH, k)


def complete_shapes(data: SpectralData, workers: int | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(labels, spectra (m, k), identity per shape) of every posed body of the data set."""
    identities = json.loads((data.root / "work" / "identities.json").read_text())
    shapes_path = data.root / "work" / "shapes.npy"
    count = len(np.load(shapes_path, mmap_mode="r"))
    k = data.spectra.shape[1]
    solved_shapes, solved = data.complete_spectra()
    spectra = np.full((count, k), np.nan)
    spectra[solved_shapes] = solved
    missing = np.flatnonzero(np.isnan(spectra).any(axis=1))
    with ProcessPoolExecutor(max_workers=workers) as pool:
        jobs = [pool.submit(_closed_spectrum, str(shapes_path), data.template.faces, int(s), k) for s in missing]
        for shape, job in zip(missing, jobs, strict=True):
            spectra[shape] = job.result()
    identity = np.arange(count) // data.shapes_per_identity
    labels = np.array([f"{identities[i]['group']}-{i:03d}" for i in identity])
    return labels, spectra, identity


def stored_bodies(data: SpectralData, models: Path) -> tuple[np.ndarray, np.ndarray]:
    """(spectra (m, k), whose person each is) of a models folder's seed database: every posed
    body of ``data``, in shape order (:func:`save_seed`), as the retrieval benchmarks query it."""
    spectra = np.load(models / SEED_FILE)["spectra"]
    return spectra, data.identity_of(np.arange(len(spectra)))


def full_coverage_pairs(pairs: PairTable) -> tuple[PairTable, PairTable]:
    """(training, held-out) pairs of parts covering the body: the held-out ones (every test split
    and variant) are the retrieval queries; a ranking for them may be fitted on the training ones."""
    full = pairs.scenario == FULL_COVERAGE
    return (
        pairs.rows(np.flatnonzero(full & (pairs.split == "train"))),
        pairs.rows(np.flatnonzero(full & ~np.isin(pairs.split, ("train", "validation")))),
    )


def save_seed(path: Path, labels: np.ndarray, spectra: np.ndarray) -> None:
    np.savez_compressed(path, labels=labels.astype(str), spectra=spectra.astype(np.float64))


def hit_rates(
    queries: np.ndarray, query_identity: np.ndarray, excluded: np.ndarray, spectra: np.ndarray, identity: np.ndarray
) -> dict[str, float]:
    """Top-1/5/10 identity hit rates; ``excluded[i]`` is the stored shape query i may not match.
    ``queries`` (n, k), or (n, m, k): each stored shape at its distance to the nearest of a
    query's m spectra (a share profile, as ``/v1/retrieve`` ranks two operands untold)."""
    hits = np.array(
        [
            identity_hits(nearest_of(query, spectra)[0], person, skip, identity)
            for query, person, skip in zip(queries, query_identity, excluded, strict=True)
        ],
        dtype=bool,
    ).reshape(-1, len(TOP))
    return {f"top{t}": float(hits[:, i].sum()) / max(len(queries), 1) for i, t in enumerate(TOP)}


def identity_hits(distance: np.ndarray, person: int, excluded: int, identity: np.ndarray) -> list[bool]:
    """For each t of TOP, whether ``person`` is among the t stored shapes nearest by ``distance``
    (one query's distance to every stored shape), the stored shape ``excluded`` left out."""
    distance = distance.copy()
    distance[excluded] = np.inf
    ranked = identity[np.argsort(distance, kind="stable")[: max(TOP)]]
    return [bool(np.any(ranked[:t] == person)) for t in TOP]


def retrieval_table(
    data: SpectralData,
    predicted_unions: dict[str, tuple[np.ndarray, np.ndarray]],
    spectra: np.ndarray,
    identity: np.ndarray,
) -> dict:
    """ShapeDNA leave-one-out on the complete shapes, and each query set of ``predicted_unions``.

    ``predicted_unions`` maps a method name to (query spectra, the shape index the scans came from).
    """
    everything = np.arange(len(spectra))
    table = {
        "shapedna_complete": {"queries": len(spectra), **hit_rates(spectra, identity, everything, spectra, identity)}
    }
    for name, (queries, shapes) in predicted_unions.items():
        table[name] = {"queries": len(queries), **hit_rates(queries, identity[shapes], shapes, spectra, identity)}
    return table
