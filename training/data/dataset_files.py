"""What a finished build leaves: ``dataset.npz``, ``manifest.json`` and ``DATASET_CARD.md``."""

import json
from dataclasses import asdict
from pathlib import Path

import numpy as np

from training.data.overlaps import CHAIN_COLUMNS
from training.data.presets import Preset


def write_dataset(
    out: Path,
    preset: Preset,
    seed: int,
    identities: list[dict],
    table: dict,
    masks: np.ndarray,
    spectra: dict,
    seconds: float,
) -> dict:
    """``dataset.npz`` with every table, ``manifest.json`` and ``DATASET_CARD.md``; returns the manifest.

    ``spectra["cell_task"]`` lists, cell by cell in :func:`training.data.spectrum_cache.spectrum_tasks`'
    order, which spectrum each table cell reads; it is cut back here into the rows' columns.
    """
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
    (out / "DATASET_CARD.md").write_text(dataset_card(manifest))
    return manifest


def dataset_card(manifest: dict) -> str:
    """The data set card: sizes, Test B's union types, failures and row counts, from the manifest."""
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
