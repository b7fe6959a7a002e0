"""``spectral-unions-train calibrate-sessions``: σ of session unions solved on their views, which
way unregistered sessions are read, and the card's sessions table.

Calibration people (their own seed) are scanned as a front-end scans (:mod:`training.sessions.
scans`), both as cut and re-meshed, and every prefix of a session in :data:`LENGTHS` is read
every way the service can (:mod:`training.sessions.reading`). Per band of view counts and per
eigenvalue, a method's relative σ is the 90th percentile of |estimate − truth| / estimate over
INTERVAL_Z, so that estimate ± INTERVAL_Z·σ holds 90 % of the calibration eigenvalues (fused for
registered views; aligned for views in their own frames, over the sessions that aligned); per
band, unregistered sessions are read aligned where that was closer on the calibration people
than the learned chain (a session that did not align counted at the chain's error, as served).
Held-out people (another seed) say how often each interval holds there. Then Test C's people are
scored as served (:mod:`training.sessions.evaluate`). Written to ``models/sessions.json``, the
manifest and the card.
"""

import json
from pathlib import Path

import numpy as np

from app.contract import INTERVAL_Z, SESSIONS_FILE
from app.inference import SpectralModels, write_manifest
from app.sessions import Bands, SessionCalibration
from training.card.glance import CARD, update_glance
from training.card.tables import replace_block
from training.sessions.card import BEGIN, END, render
from training.sessions.evaluate import evaluate_sessions
from training.sessions.reading import Read, read_prefixes, session_views
from training.sessions.scans import EVERYONE, VARIANTS, K, people, relative_error

BANDS = (3, 8, 16, 32)  # a band holds sessions of more views than the band before, up to this many
LENGTHS = (2, 3, 4, 6, 8, 12, 16, 24, 32)
COVERAGE = 0.90


def reads(models: SpectralModels, count: int, seed: int) -> list[Read]:
    """Every session prefix of ``count`` people of ``seed``, both deliveries, read every way."""
    sampler, found = people(count, seed, EVERYONE)  # children too: the people scanned are
    faces = sampler.template.faces
    out = []
    for number, person in enumerate(found):
        for variant in VARIANTS:
            views = session_views(models, person, faces, variant)
            out += read_prefixes(models, person, faces, views, LENGTHS, np.random.default_rng([seed, number]))
    return out


def band_of(views: int) -> int:
    """Which band a session's view count falls in."""
    return min(int(np.searchsorted(BANDS, views)), len(BANDS) - 1)


def _sigma(estimates: list[np.ndarray], truths: list[np.ndarray]) -> np.ndarray:
    relative = np.abs(np.array(estimates) - np.array(truths)) / np.array(estimates)
    return np.quantile(relative, COVERAGE, axis=0) / INTERVAL_Z


def _held(estimates: list[np.ndarray], truths: list[np.ndarray], sigma: np.ndarray) -> float | None:
    if not estimates:
        return None
    gap = np.abs(np.array(estimates) - np.array(truths))
    return round(float(np.mean(gap <= INTERVAL_Z * sigma * np.array(estimates))), 4)


def _unregistered_error(read: Read) -> float:
    """The error of an aligned reading as served: aligned and chained where a few views did not
    come together, the chain's where more did not."""
    return relative_error(read.unregistered_aligned(), read.truth)


def fit_bands(fit: list[Read], test: list[Read]) -> dict[str, list[dict]]:
    """Per band: fused and aligned σ, and how unregistered sessions are read, with held-out figures."""
    methods: dict[str, list[dict]] = {"fused": [], "aligned": []}
    for band, up_to in enumerate(BANDS):
        rows = [r for r in fit if band_of(r.views) == band]
        tested = [r for r in test if band_of(r.views) == band]
        if not rows:
            raise ValueError(f"no calibration session of up to {up_to} views: scan more people")
        methods["fused"].append(_fused_band(up_to, rows, tested))
        methods["aligned"].append(_aligned_band(up_to, rows, tested))
    return methods


def _fused_band(up_to: int, rows: list[Read], tested: list[Read]) -> dict:
    """One band's σ of fused unions, fitted on ``rows``, held on ``tested``."""
    fused = _sigma([r.fused for r in rows], [r.truth for r in rows])
    return {
        "views_up_to": up_to,
        "relative_sigma": np.round(fused, 6).tolist(),
        "sessions": len(rows),
        "held_out_sessions": len(tested),
        "held_out_coverage": _held([r.fused for r in tested], [r.truth for r in tested], fused),
    }


def _aligned_band(up_to: int, rows: list[Read], tested: list[Read]) -> dict:
    """One band's σ of aligned unions (over the sessions that aligned, the fused where none
    did), and whether its unregistered sessions are read aligned or through the chain."""
    aligned_rows = [r for r in rows if r.aligned is not None] or rows
    aligned = _sigma(
        [r.aligned if r.aligned is not None else r.fused for r in aligned_rows], [r.truth for r in aligned_rows]
    )
    closer = np.mean([_unregistered_error(r) for r in rows]) < np.mean([relative_error(r.chain, r.truth) for r in rows])
    tested_aligned = [r for r in tested if r.aligned is not None]
    return {
        "views_up_to": up_to,
        "relative_sigma": np.round(aligned, 6).tolist(),
        "unregistered_by": "aligned" if closer else "learned-chain",
        "sessions": len(rows),
        "aligned_sessions": sum(r.aligned is not None for r in rows),
        "held_out_sessions": len(tested),
        "held_out_coverage": _held([r.aligned for r in tested_aligned], [r.truth for r in tested_aligned], aligned),
    }


def calibrate_sessions(models: Path, count: int, held_out: int, seed: int, test_c: int, command: str) -> dict:
    """Fit on ``count`` people of ``seed``, hold out ``held_out`` of ``seed + 1``, score the
    sessions as served on ``test_c`` of Test C's people; write ``models/sessions.json``, the
    manifest and the card's sessions section; return what was written."""
    (models / SESSIONS_FILE).unlink(missing_ok=True)  # the models as served, without the calibration it replaces
    write_manifest(models)
    served = SpectralModels(models)
    methods = fit_bands(reads(served, count, seed), reads(served, held_out, seed + 1))
    calibration = SessionCalibration(
        Bands.of(methods["fused"], K, "fused"),
        Bands.of(methods["aligned"], K, "aligned"),
        tuple(band["unregistered_by"] for band in methods["aligned"]),
    )
    content = {
        "people": count,
        "held_out_people": held_out,
        "seed": seed,
        "lengths": list(LENGTHS),
        "interval_z": INTERVAL_Z,
        "methods": {name: {"bands": bands} for name, bands in methods.items()},
        "test_c_people": test_c,
        "evaluation": evaluate_sessions(served, calibration, test_c),
    }
    (models / SESSIONS_FILE).write_text(json.dumps(content, indent=1) + "\n")
    write_manifest(models)
    replace_block(models / CARD, BEGIN, END, render(content, command))
    update_glance(models)
    return content
