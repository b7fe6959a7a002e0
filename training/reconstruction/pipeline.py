"""From the bodies build to ``models/reconstruction.onnx``: train, export, check, evaluate.

The decoder's figures go to ``models/reconstruction.json`` and their own section of the model
card (the union pipeline's ``metrics.json`` and section are left as they are); the manifest is
rewritten so the service verifies and serves the new graph.
"""

import json
import time
from dataclasses import replace
from pathlib import Path

import numpy as np
import torch

from app.contract import RECONSTRUCTION_FILE
from app.inference import write_manifest
from training.card.glance import update_glance
from training.card.tables import replace_block
from training.common.data import SpectralData
from training.reconstruction.bodies import BODIES_FILE
from training.reconstruction.decoder import DecoderConfig, ShapeBasis
from training.reconstruction.evaluate import evaluate_decoder
from training.reconstruction.export import decoder_parity, export_decoder
from training.reconstruction.train import DecoderTraining, data_set_rest_bodies, split_bodies, train_decoder
from training.union.predictors import served_predictors

METRICS_FILE = "reconstruction.json"
BEGIN, END = "<!-- reconstruction:begin -->", "<!-- reconstruction:end -->"
BASIS_SIZES = (4, 8, 12, 16, 20, 24, 32, 48)  # components, for the card's "how many" curve

DECODER_PRESETS = {
    "tiny": (
        DecoderTraining(epochs=3, batch=16, first_restart=3, union_rows=32, partial_rows=32),
        DecoderConfig(components=8, width=32),
    ),
    "standard": (DecoderTraining(), DecoderConfig()),
    # The comparison: the bodies build's own pairs' unions as rows too (needs `build-bodies --pairs`).
    "standard-body-unions": (DecoderTraining(body_unions=True), DecoderConfig()),
    # The comparison: no partial-union rows, no scans (decision 012).
    "standard-no-partial": (DecoderTraining(partial_rows=0, body_scans=False), DecoderConfig()),
    # The comparison: partial-union rows but no scans (decision 012).
    "standard-no-scans": (DecoderTraining(body_scans=False), DecoderConfig()),
}


def basis_curve(rest: np.ndarray, seed: int) -> dict[str, dict[str, float]]:
    """Vertex error (mm) of the validation bodies projected on bases of each size of BASIS_SIZES."""
    train, validation = split_bodies(len(rest), seed)
    largest = ShapeBasis.fit(rest[train], min(max(BASIS_SIZES), len(train) - 1))
    curve = {}
    for size in BASIS_SIZES:
        if size > len(largest.scales):
            break
        basis = ShapeBasis(largest.mean, largest.components[:size], largest.scales[:size])
        error = np.linalg.norm(basis.bodies(basis.coefficients(rest[validation])) - rest[validation], axis=-1) * 1e3
        curve[str(size)] = {"mean_mm": float(error.mean()), "p95_mm": float(np.percentile(error, 95))}
    return curve


def run_decoder_pipeline(
    bodies_dir: Path, data_dir: Path, union_run: Path, runs: Path, models: Path, preset: str, seed: int, command: str
) -> dict:
    started = time.perf_counter()
    settings, config = DECODER_PRESETS[preset]
    settings = replace(settings, seed=seed)
    data = SpectralData(data_dir, seed=seed)
    decoder = train_decoder(bodies_dir, runs / "decoder.pt", settings, config, data, union_run)
    trained = time.perf_counter()
    export_decoder(decoder, models / RECONSTRUCTION_FILE)
    write_manifest(models)
    arrays = np.load(bodies_dir / BODIES_FILE)
    rest = arrays["rest"].astype(np.float64)
    spectra = arrays["spectra"]
    train_ids, _ = split_bodies(len(rest), seed)
    union, _ = served_predictors(models)
    reference = (spectra[train_ids].reshape(-1, spectra.shape[2]), np.repeat(rest[train_ids], spectra.shape[1], 0))
    mean_body = decoder.mean.numpy().reshape(-1, 3).astype(np.float64)
    measured = spectra[:, 0]
    parity_sigma = 0.05 * measured * (np.arange(len(measured)) % 2)[:, None]  # measured and predicted rows

    @torch.no_grad()
    def decode(queries: np.ndarray, sigma: np.ndarray) -> np.ndarray:
        inputs = (torch.as_tensor(x, dtype=torch.float32) for x in (queries, sigma))
        return decoder(*inputs).numpy().astype(np.float64)

    metrics = {
        "sets": evaluate_decoder(
            data,
            decode,
            union,
            mean_body,
            reference,
            data_set_rest_bodies(data).astype(np.float64),
        ),
        "basis_mm": basis_curve(rest, seed),
        "parity_max_relative": decoder_parity(decoder, models / RECONSTRUCTION_FILE, measured, parity_sigma),
        "config": config.as_dict() | {"k": decoder.config.k},
        "training_identities": len(train_ids),
        "seconds": {"training": round(trained - started, 1), "total": round(time.perf_counter() - started, 1)},
        "bodies": json.loads((bodies_dir / "manifest.json").read_text()),
    }
    (models / METRICS_FILE).write_text(json.dumps(metrics, indent=1))
    replace_block(models / "MODEL_CARD.md", BEGIN, END, render(metrics, command))
    update_glance(models)
    return metrics


def render(metrics: dict, command: str) -> str:
    """The card's reconstruction tables."""
    lines = [
        BEGIN,
        f"Produced by `{command}`.",
        "",
        "| queries | n (identities) | decoder mean / p95 vertex mm | height mm | area | spectrum round trip (p5–p95) "
        "| mean body mean / p95 mm | nearest identity mean / p95 mm |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for name, row in metrics["sets"].items():
        ours, mean, nearest = row["decoder"], row["mean_body"], row["nearest_identity"]
        lines.append(
            f"| {name} | {row['queries']} ({row['identities']}) | {ours['vertex_mean_mm']:.1f} / "
            f"{ours['vertex_p95_mm']:.1f} | {ours['height_mm']:.1f} | {100 * ours['area_relative']:.1f} % | "
            f"{100 * ours['spectrum_mre']:.1f} % ({100 * ours['spectrum_p05']:.0f}–{100 * ours['spectrum_p95']:.0f}) | "
            f"{mean['vertex_mean_mm']:.1f} / {mean['vertex_p95_mm']:.1f} | "
            f"{nearest['vertex_mean_mm']:.1f} / {nearest['vertex_p95_mm']:.1f} |"
        )
    lines += ["", "Baselines' height / area errors:", ""]
    for name, row in metrics["sets"].items():
        mean, nearest = row["mean_body"], row["nearest_identity"]
        lines.append(
            f"- {name}: mean body {mean['height_mm']:.1f} mm / {100 * mean['area_relative']:.1f} %, nearest identity "
            f"{nearest['height_mm']:.1f} mm / {100 * nearest['area_relative']:.1f} %"
        )
    curve = ", ".join(f"{size}: {v['mean_mm']:.2f} / {v['p95_mm']:.2f}" for size, v in metrics["basis_mm"].items())
    lines += [
        "",
        f"Shape basis, validation bodies projected (components: mean / p95 mm): {curve}.",
        f"ONNX parity (largest difference relative to the output's scale): {metrics['parity_max_relative']:.1e}.",
        END,
    ]
    return "\n".join(lines)
