"""Which spectra a table needs, once each, and the ones a build has already solved.

A table refers to parts and unions through (shape, mask, variant) cells; many cells are the
same task (a part reused by its nested and identical pairs, a union shared by a chain), and
each distinct task is solved once. Solved spectra are cached on disk by what they are the
spectrum of, so a build whose splits changed still reuses every spectrum it computed before.
"""

import hashlib
from pathlib import Path

import numpy as np

from training.data.overlaps import CHAIN_COLUMNS
from training.data.spectra import MESH, VARIANTS


def spectrum_tasks(table: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Distinct (shape, mask) tasks, their variants, and, per table cell, the task it reads.

    Cells in order: the rows' parts A, parts B and unions, the triples' five columns, the
    chains' views and prefix unions (what :func:`training.data.dataset_files.write_dataset`
    cuts them back into).
    """
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


def task_keys(tasks: np.ndarray, variants: np.ndarray, masks: np.ndarray) -> np.ndarray:
    """A content key per (shape, mask, variant) task: the shape's index, the mask's bits, the variant."""
    keys = [
        hashlib.blake2b(
            np.int64(shape).tobytes() + masks[mask].tobytes() + str(variant).encode(), digest_size=16
        ).digest()
        for (shape, mask, _), variant in zip(tasks, variants, strict=True)
    ]
    return np.array(keys, dtype="S16")


def cached_spectra(work: Path) -> dict[bytes, np.ndarray]:
    """Every spectrum saved in ``work``'s ``spectra-*.npz`` chunks, by task key."""
    cached: dict[bytes, np.ndarray] = {}
    for path in sorted(work.glob("spectra-*.npz")):
        with np.load(path) as chunk:
            cached.update(zip(chunk["keys"], chunk["values"], strict=True))
    return cached


def next_chunk_number(work: Path) -> int:
    """The number the next ``spectra-*.npz`` chunk is saved under (after every saved one)."""
    return 1 + max((int(path.stem.split("-")[1]) for path in work.glob("spectra-*.npz")), default=-1)
