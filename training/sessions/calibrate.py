"""``spectral-unions-train calibrate-sessions``: σ of fused session unions, measured on anny.

Calibration people (their own seed) are scanned as a front-end scans (:mod:`training.sessions.
scans`), both as cut and re-meshed; every prefix of a session in :data:`LENGTHS` is fused and
solved as the service solves a registered session, and compared with its exact union. Per band
of view counts and per eigenvalue, the relative σ is the 90th percentile of |fused − truth| /
fused over INTERVAL_Z, so that fused ± INTERVAL_Z·σ holds 90 % of the calibration eigenvalues;
held-out people (another seed) say how often it holds on people it was not fitted on. Written to
``models/sessions.json`` (and the manifest), with the per-band errors the card reports.
"""

import json
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from app.contract import INTERVAL_Z, SESSIONS_FILE
from app.inference.manifest import write_manifest
from app.sessions.fused import fused_spectrum, view_of_part
from training.sessions.scans import VARIANTS, K, people, solved_view, union_spectrum, view_meshes

BANDS = (3, 8, 16, 32)  # a band holds sessions of more views than the band before, up to this many
LENGTHS = (2, 3, 4, 6, 8, 10, 12, 16, 20, 24, 28, 32)
COVERAGE = 0.90


@dataclass(frozen=True)
class Residuals:
    """Per fused session: its view count, and |fused − truth| / fused for each eigenvalue."""

    views: np.ndarray  # (s,)
    relative: np.ndarray  # (s, k)
    error: np.ndarray  # (s,) mean |fused − truth| / truth


def residuals(count: int, seed: int) -> Residuals:
    """Every session prefix of ``count`` people of ``seed``, both variants, fused against truth."""
    sampler, found = people(count, seed)
    faces = sampler.template.faces
    views, relative, error = [], [], []
    for person in found:
        for variant in VARIANTS:
            solved = [view_of_part(solved_view(mesh).part) for mesh in view_meshes(person, faces, variant)]
            for length in LENGTHS:
                if length > len(solved):
                    continue
                truth = union_spectrum(person.body, faces, person.masks[:length])
                fused = fused_spectrum(solved[:length], K)
                views.append(length)
                relative.append(np.abs(fused - truth) / fused)
                error.append(float(np.mean(np.abs(fused - truth) / truth)))
    return Residuals(np.array(views), np.array(relative), np.array(error))


def band_of(views: np.ndarray) -> np.ndarray:
    """Which band each session's view count falls in."""
    return np.minimum(np.searchsorted(BANDS, views), len(BANDS) - 1)


def calibrate_sessions(models: Path, count: int, held_out: int, seed: int) -> dict:
    """Fit the bands on ``count`` people of ``seed``, score them on ``held_out`` people of
    ``seed + 1``; write ``models/sessions.json`` and the manifest; return what was written."""
    fit, test = residuals(count, seed), residuals(held_out, seed + 1)
    bands = []
    for band, up_to in enumerate(BANDS):
        rows, tested = band_of(fit.views) == band, band_of(test.views) == band
        if not rows.any():
            raise ValueError(f"no calibration session of up to {up_to} views: scan more people")
        sigma = np.quantile(fit.relative[rows], COVERAGE, axis=0) / INTERVAL_Z
        held = test.relative[tested] <= INTERVAL_Z * sigma if tested.any() else np.zeros((0, K), bool)
        bands.append(
            {
                "views_up_to": up_to,
                "relative_sigma": np.round(sigma, 6).tolist(),
                "sessions": int(rows.sum()),
                "held_out_sessions": int(tested.sum()),
                "held_out_coverage": round(float(held.mean()), 4) if held.size else None,
                "held_out_error": round(float(test.error[tested].mean()), 4) if tested.any() else None,
            }
        )
    content = {
        "method": "fused",
        "people": count,
        "held_out_people": held_out,
        "seed": seed,
        "lengths": list(LENGTHS),
        "interval_z": INTERVAL_Z,
        "bands": bands,
    }
    (models / SESSIONS_FILE).write_text(json.dumps(content, indent=1) + "\n")
    write_manifest(models)
    return content
