"""``spectral-unions-train fit-bodies``: the body basis sessions are fitted with, its calibration,
and the card's bodies section.

The basis is the shape decoder's own (read back from ``reconstruction.onnx``), posed by anny's
skinning summed per template part (:func:`training.data.template.part_weights`), written to
``models/body.npz``. Calibration people (their own seed) are scanned as a front-end scans
(:mod:`training.sessions.scans`), each prefix of their session fitted as ``/v1/sessions/{id}/body``
fits it, and the factors that make the vertices' σ and the measurements' intervals hold 90 % of
the truth are stored with the basis. Then Test C's people are scored: the fitted body's vertex
error against the person at rest, beside the mean body; each measurement against the same
measurement on the true body; how often the intervals hold.
"""

import json
from dataclasses import replace
from pathlib import Path

import numpy as np

from app.contract import BODY_FILE, INTERVAL_Z, RECONSTRUCTION_FILE
from app.geometry import Mesh
from app.inference import MEASUREMENTS, BodyBasis, Measurer, SpectralModels, write_manifest
from app.sessions import (
    Candidate,
    NoBodyFits,
    SessionBody,
    SessionView,
    fitted_session,
    fused_spectrum,
    ranked_rows,
    session_body,
    session_coverage,
    session_union,
    stored_body,
    unknown_warning,
)
from training.card.glance import CARD, update_glance
from training.card.tables import replace_block
from training.reconstruction.evaluate import closed_spectrum, rigidly_aligned
from training.reconstruction.export import decoder_basis
from training.sessions.body_card import BEGIN, END, render
from training.sessions.identities import (
    Gallery,
    fitted_scale,
    rank_of,
    rest_coefficients,
    write_seed_bodies,
)
from training.sessions.reading import moved, session_views
from training.sessions.scans import EVERYONE, VARIANTS, Person, people, solved_view, test_c_people

LENGTHS = (3, 5, 12, 24)
ANSWERED = 5  # people an identity answers (its top)
BANDS = (5, 12, 32)  # the intervals are calibrated per band of view counts: up to 5, 12, any more
UNREGISTERED_LENGTH = 5  # views in their own frames, aligned first: scored at this length
BODIES_METRICS = "bodies.json"
FRAMES_STREAM = 13  # the random frames unregistered views are sent in


def body_basis(models: Path) -> BodyBasis:
    """The decoder's shape basis with anny's skinning per part, uncalibrated."""
    from training.data.bodies import BodyModel
    from training.data.template import part_weights

    mean, components = decoder_basis(models / RECONSTRUCTION_FILE)
    anny = BodyModel()
    weights = part_weights(anny.model, anny.topology)
    return BodyBasis(mean.reshape(-1, 3), components.reshape(len(components), -1, 3), weights)


def _fitted(served: SpectralModels, basis: BodyBasis, views: list[SessionView], registered: bool) -> SessionBody:
    """The body and measurements ``/v1/sessions/{id}/body`` answers for ``views``, with ``basis``."""
    return session_body(basis, served.measurer, views, registered, session_coverage(served, views))


def _scores(body: SessionBody, person: Person, measurer: Measurer, basis: BodyBasis) -> dict:
    """One fit against the truth: vertex errors and σ, each measurement's error and spread."""
    error = np.linalg.norm(rigidly_aligned(body.vertices, person.rest) - person.rest, axis=1)
    mean_error = np.linalg.norm(rigidly_aligned(basis.mean, person.rest) - person.rest, axis=1)
    truth, mean_body = measurer.measure(person.rest), measurer.measure(basis.mean)
    measured = {
        m.name: {
            "error": m.value - truth[m.name],
            "half": (m.upper - m.lower) / 2,
            "mean_body_error": mean_body[m.name] - truth[m.name],
        }
        for m in body.measurements
        if truth[m.name] is not None and mean_body[m.name] is not None
    }
    return {
        "vertex_mm": float(1e3 * error.mean()),
        "vertex_p95_mm": float(1e3 * np.percentile(error, 95)),
        "mean_body_mm": float(1e3 * mean_error.mean()),
        "vertex_ratio": (error / np.maximum(body.sigma, 1e-9)).tolist(),
        "measured": measured,
        "not_measured": list(body.not_measured),
        "residual_m": body.fitted.residual_m,
    }


def _scanned(served: SpectralModels, found: list[Person]) -> dict[tuple[int, str], list[SessionView]]:
    """Each person's session, as cut and re-meshed, solved and placed once (keyed by the person's
    number and the variant): the calibration reads it twice."""
    faces = served.template.faces
    return {
        (number, variant): session_views(served, person, faces, variant)
        for number, person in enumerate(found)
        for variant in VARIANTS
    }


def _fit_residual(basis: BodyBasis, template: np.ndarray, scanned: dict[tuple[int, str], list[SessionView]]) -> float:
    """The median gap (m) that the registered fits to ``scanned``'s session prefixes leave
    between their points and the body: what a fit that holds leaves (:meth:`BodyBasis.misfit`)."""
    gaps = []
    for views in scanned.values():
        for length in (length for length in LENGTHS if length <= len(views)):
            try:
                gaps.append(fitted_session(basis, template, views[:length], registered=True).residual_m)
            except NoBodyFits:
                continue
    return float(np.median(gaps))


def _sessions(
    served: SpectralModels,
    basis: BodyBasis,
    found: list[Person],
    scanned: dict[tuple[int, str], list[SessionView]],
    gallery: Gallery,
) -> list[dict]:
    """Every person's session prefixes fitted (registered at each length, in their own frames at
    UNREGISTERED_LENGTH), scored, and ranked against ``gallery``; a session whose views did not
    come together is counted, not scored."""
    faces = served.template.faces
    measurer = served.measurer  # the served models hold the basis being calibrated, so their measurer too
    rows = []
    for (number, variant), views in scanned.items():
        person = found[number]
        ceiling = gallery.person_distances(closed_spectrum(person.rest, faces, served.k))
        for length in LENGTHS:
            if length > len(views):
                continue
            prefix = views[:length]
            row = {"views": length, "variant": variant, "registered": True}
            try:
                body = _fitted(served, basis, prefix, registered=True)
            except NoBodyFits:  # answered 409 body-not-fitted: counted, not scored
                rows.append(row | {"fitted": False})
                continue
            today = {"today": gallery.person_distances(_decoded_union(served, prefix)), "ceiling": ceiling}
            scores = _scores(body, person, measurer, basis) | _ranked(body, person, served, gallery)
            rows.append(row | {"fitted": True} | scores | today)
        prefix = views[:UNREGISTERED_LENGTH]
        frames = moved(prefix, np.random.default_rng([FRAMES_STREAM, number]))
        sent = [replace(view, geometry=frame) for view, frame in zip(prefix, frames, strict=True)]
        row = {"views": len(sent), "variant": variant, "registered": False}
        try:
            body = _fitted(served, basis, sent, registered=False)
        except NoBodyFits:  # answered 409 body-not-fitted: counted, not scored
            rows.append(row | {"fitted": False})
            continue
        rows.append(
            row
            | {"fitted": True, "ceiling": ceiling}
            | _scores(body, person, measurer, basis)
            | _ranked(body, person, served, gallery)
        )
    return rows


def _ranked(body: SessionBody, person: Person, served: SpectralModels, gallery: Gallery) -> dict:
    """The fitted body against the gallery: every person's distance by shape (as served) and by
    the fitted body's closed spectrum (as served before)."""
    spectrum = closed_spectrum(body.vertices, served.template.faces, served.k)
    shape, by_spectrum = gallery.shape_distances(body.fitted), gallery.person_distances(spectrum)
    return {"label": person.label, "shape": shape, "distances": by_spectrum}


def _decoded_union(served: SpectralModels, views: list[SessionView]) -> np.ndarray:
    """What the service ranked a session by before: its union (registered: fused) decoded into a
    body by the shape decoder, that body's closed spectrum."""
    fused = fused_spectrum([view.geometry for view in views], served.k)
    union = session_union(served, views, "fused", fused).estimate
    decoded = served.reconstruct(union.eigenvalues, union.sigma)
    return closed_spectrum(decoded, served.template.faces, served.k)


def _posed_spread(served: SpectralModels, basis: BodyBasis, found: list[Person]) -> float:
    """σ per whitened coefficient of a whole posed body's fit (solved, placed and fitted as
    ``POST /v1/shapes`` stores a scan's body) around the person's shape at rest."""
    deviations = []
    for person in found:
        solved = solved_view(Mesh(person.body, served.template.faces))
        stored = stored_body(basis, served.template.vertices, served.correspondence, solved.part)
        if stored is not None:
            deviations.append(stored.coefficients - rest_coefficients(basis, person.rest))
    return float(np.sqrt(np.mean(np.square(deviations))))


def _scales(rows: list[dict]) -> tuple[float, float]:
    """The factors that make 90 % of ``rows``' vertex errors and measurement errors fall inside Z σ."""
    vertex = np.concatenate([row["vertex_ratio"] for row in rows])
    measured = [m for row in rows for m in row["measured"].values() if m["half"] > 0]
    spread = [abs(m["error"]) / m["half"] * INTERVAL_Z for m in measured]
    return float(np.quantile(vertex, 0.9) / INTERVAL_Z), float(np.quantile(spread, 0.9) / INTERVAL_Z)


def _identity(rows: list[dict], basis: BodyBasis) -> dict:
    """How often the person scanned is answered first and among the first ANSWERED by shape, the
    first's mean confidence as served, how often the answer says the person is probably not
    stored when they are, and when they are not (their own shapes taken out of the gallery); the
    same first-place rate for the fitted body's closed spectrum and the union decoded (the
    service's rankings before; decoded: registered sessions) and for the true body's spectrum at
    rest (a spectrum's ceiling); ``basis``: its identity scale and how far a fit that holds as
    each row's did takes the person for one not stored."""
    unknown = [basis.unknown_for(row["residual_m"]) for row in rows]
    scale = basis.shape_identity_scale
    answers = [_by_shape(row["shape"], scale, far) for row, far in zip(rows, unknown, strict=True)]
    strangers = [
        _by_shape({k: d for k, d in row["shape"].items() if k != row["label"]}, scale, far)
        for row, far in zip(rows, unknown, strict=True)
    ]
    today = [rank_of(row["today"], row["label"]) == 0 for row in rows if "today" in row]
    return {
        "top1": float(np.mean([a[0].label == row["label"] for a, row in zip(answers, rows, strict=True)])),
        "top5": float(np.mean([row["label"] in {c.label for c in a} for a, row in zip(answers, rows, strict=True)])),
        "confidence": float(np.mean([a[0].confidence for a in answers])),
        "stored_warned": _warned(answers, unknown),
        "not_stored_warned": _warned(strangers, unknown),
        "spectrum_top1": float(np.mean([rank_of(row["distances"], row["label"]) == 0 for row in rows])),
        "today_top1": float(np.mean(today)) if today else None,
        "ceiling_top1": float(np.mean([rank_of(row["ceiling"], row["label"]) == 0 for row in rows])),
    }


def _warned(answers: list[list[Candidate]], unknown: list[float]) -> float:
    """How often the answers say the person scanned is probably not stored."""
    return float(np.mean([bool(unknown_warning(a[0], far)) for a, far in zip(answers, unknown, strict=True)]))


def _by_shape(person_distances: dict[str, float], scale: float, unknown: float) -> list[Candidate]:
    """The people answered from each person's shape distance, as the route answers them."""
    return ranked_rows([(label, label, d) for label, d in person_distances.items()], ANSWERED, scale, unknown)


def summary(rows: list[dict], basis: BodyBasis) -> dict:
    """Per reading (views / registered): vertex error, the mean body's, interval coverage, per
    measurement the mean absolute error (mm), the mean body's, coverage and how often measured,
    and identity (:func:`_identity`, as ``basis`` ranks and warns)."""
    out = {}
    for key in sorted({(row["views"], row["registered"]) for row in rows}):
        tried = [row for row in rows if (row["views"], row["registered"]) == key]
        chosen = [row for row in tried if row["fitted"]]
        if not chosen:
            continue
        ratios = np.concatenate([row["vertex_ratio"] for row in chosen])
        taken = {name: [row["measured"][name] for row in chosen if name in row["measured"]] for name in MEASUREMENTS}
        per = {name: _measurement(taken[name]) for name in MEASUREMENTS}
        out[f"{key[0]}/{'registered' if key[1] else 'unregistered'}"] = {
            "sessions": len(tried),
            "fitted": len(chosen),
            "vertex_mm": float(np.mean([row["vertex_mm"] for row in chosen])),
            "vertex_p95_mm": float(np.mean([row["vertex_p95_mm"] for row in chosen])),
            "mean_body_mm": float(np.mean([row["mean_body_mm"] for row in chosen])),
            "vertex_held": float(np.mean(ratios <= INTERVAL_Z)),
            "measurements": per,
            "identity": _identity(chosen, basis),
        }
    return out


def _measurement(taken: list[dict]) -> dict:
    """One measurement over the fits that gave it: how many, its mean absolute error and the mean
    body's (mm), and how often its interval held; None where no fit gave it."""
    if not taken:
        return {"measured": 0, "mae_mm": None, "mean_body_mae_mm": None, "held": None}
    return {
        "measured": len(taken),
        "mae_mm": float(1e3 * np.mean([abs(t["error"]) for t in taken])),
        "mean_body_mae_mm": float(1e3 * np.mean([abs(t["mean_body_error"]) for t in taken])),
        "held": float(np.mean([abs(t["error"]) <= t["half"] for t in taken])),
    }


def fit_bodies(models: Path, count: int, seed: int, test_c: int, command: str) -> dict:
    """Write the uncalibrated basis, calibrate it on ``count`` people of ``seed`` (each stored at
    rest beside the seed database for the identity's scale), write it again with its factors,
    score Test C's first ``test_c`` people against the seed database; write
    ``models/bodies.json``, the manifest and the card's bodies section; return the metrics."""
    basis = body_basis(models)
    basis.save(models / BODY_FILE)
    write_seed_bodies(models, basis)
    write_manifest(models)
    served = SpectralModels(models)
    faces, seed_gallery = served.template.faces, Gallery.seed(models)
    _, calibration_people = people(count, seed, EVERYONE)  # children too: a third of the people scanned are
    stored = np.array([closed_spectrum(person.rest, faces, served.k) for person in calibration_people])
    at_rest = np.array([rest_coefficients(basis, person.rest) for person in calibration_people])
    gallery = seed_gallery.with_people([person.label for person in calibration_people], stored, at_rest)
    scanned = _scanned(served, calibration_people)
    basis = replace(basis, fit_residual_m=_fit_residual(basis, served.template.vertices, scanned))
    rows = [row for row in _sessions(served, basis, calibration_people, scanned, gallery) if row["fitted"]]
    lower = (0, *BANDS[:-1])
    scales = [
        _scales([row for row in rows if low < row["views"] <= high]) for low, high in zip(lower, BANDS, strict=True)
    ]
    sigma_scale, spread_scale = tuple(s[0] for s in scales), tuple(s[1] for s in scales)
    identity_scale = fitted_scale([(row["distances"], row["label"]) for row in rows])
    shape_scale = fitted_scale([(row["shape"], row["label"]) for row in rows])
    # no calibration person's own shape was farther, for a fit that held as well as theirs
    unknown = max(row["shape"][row["label"]] / basis.misfit(row["residual_m"]) for row in rows)
    posed_spread = _posed_spread(served, basis, calibration_people)
    basis = replace(
        basis,
        bands=BANDS,
        sigma_scale=sigma_scale,
        spread_scale=spread_scale,
        identity_scale=identity_scale,
        shape_identity_scale=shape_scale,
        posed_spread=posed_spread,
        unknown_distance=unknown,
    )
    basis.save(models / BODY_FILE)
    write_manifest(models)
    served = SpectralModels(models)
    _, found = test_c_people(test_c)
    evaluated = _sessions(served, served.body, found, _scanned(served, found), seed_gallery)
    content = {
        "people": count,
        "seed": seed,
        "test_c_people": test_c,
        "bands": list(BANDS),
        "sigma_scale": list(sigma_scale),
        "spread_scale": list(spread_scale),
        "identity_scale": identity_scale,
        "shape_identity_scale": shape_scale,
        "posed_spread": posed_spread,
        "unknown_distance": unknown,
        "calibration": summary([row | {"fitted": True} for row in rows], basis),
        "fit_residual_m": basis.fit_residual_m,
        "evaluation": summary(evaluated, served.body),
        "command": command,
    }
    (models / BODIES_METRICS).write_text(json.dumps(content, indent=1) + "\n")
    replace_block(models / CARD, BEGIN, END, render(content, command))
    update_glance(models)
    return content
