"""How well the decoder rebuilds unknown people, against the mean body and the nearest identity.

Queries, all of the benchmark's unknown identities (unknown men, unknown women, children),
whom neither the decoder nor the union operator saw: (a) the true complete spectrum of every
posed body; (b) the served operator's union of two parts that cover the body (Test A's
full-coverage pairs); (c) the union of a Test C scanning session, its five views chained, σ
carried as the service carries it; (d) the true spectrum of (c)'s five views, σ = 0: what one
upload of the views merged, or any single partial scan, asks of the decoder; (e) each complete
posed body of (a) scanned with blind spots (:mod:`training.reconstruction.blind_spots`, drawn
with their own seed), as a complete scan really arrives. The decoder reads each with its σ
(0 for (a), (d) and (e)). Each
rebuilt body is compared with the person's rest-pose body after a rigid alignment (rotation and
translation, Kabsch): mean and 95th-percentile vertex error, height and area error. The loop is
closed on the spectrum: the rebuilt body's own spectrum, by the service's engine, against the
spectrum it was decoded from. Baselines on the same rows: the basis's mean body, and the
training body nearest by the ShapeDNA distance (of 1 000+ identities).
"""

import json
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor

import numpy as np
from threadpoolctl import threadpool_limits

from app.geometry import Mesh, SpectrumOptions, mesh_spectrum
from app.inference import SpectralModels, body_height, chained_sigma, spectrum_gap, surface_area
from app.retrieval import features
from training.common.data import SpectralData
from training.data.spectra import MESH
from training.reconstruction.blind_spots import blind_spot_spectra

UNKNOWN_GROUPS = ("unknown_man", "unknown_woman", "child")
BLIND_SPOT_SEED = 2026  # the test scans' blind spots: not the training rows' draws
Decoder = Callable[[np.ndarray, np.ndarray], np.ndarray]  # (n, k) spectra, their σ → (n, V, 3) bodies
Union = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]  # (n, k), (n, k) → union, σ
Queries = tuple[np.ndarray, np.ndarray, np.ndarray]  # spectra (n, k), their σ (n, k), identity (n,)


def rigidly_aligned(moving: np.ndarray, fixed: np.ndarray) -> np.ndarray:
    """``moving`` (V, 3) rotated and translated onto ``fixed`` (same vertex order), least squares."""
    mc, fc = moving.mean(0), fixed.mean(0)
    u, _, vt = np.linalg.svd((moving - mc).T @ (fixed - fc))
    d = np.sign(np.linalg.det(u @ vt))
    rotation = u @ np.diag([1.0, 1.0, d]) @ vt
    return (moving - mc) @ rotation + fc


def body_scores(predicted: np.ndarray, truth: np.ndarray, faces: np.ndarray) -> dict[str, float]:
    """Vertex error (mm, mean and 95th percentile over every vertex of every row), height (mm)
    and area (relative) error, after rigid alignment; (n, V, 3) each."""
    errors, heights, areas = [], [], []
    for p, t in zip(predicted, truth, strict=True):
        errors.append(np.linalg.norm(rigidly_aligned(p, t) - t, axis=1))
        heights.append(abs(body_height(p) - body_height(t)))
        areas.append(abs(surface_area(p, faces) / surface_area(t, faces) - 1))
    errors_mm = 1e3 * np.concatenate(errors)
    return {
        "vertex_mean_mm": float(errors_mm.mean()),
        "vertex_p95_mm": float(np.percentile(errors_mm, 95)),
        "height_mm": float(1e3 * np.mean(heights)),
        "area_relative": float(np.mean(areas)),
    }


@threadpool_limits.wrap(limits=1)
def closed_spectrum(vertices: np.ndarray, faces: np.ndarray, k: int) -> np.ndarray:
    return np.asarray(mesh_spectrum(Mesh(vertices.astype(np.float64), faces), SpectrumOptions(k=k)).eigenvalues)


def closed_spectra(bodies: np.ndarray, faces: np.ndarray, k: int, workers: int | None = None) -> np.ndarray:
    """(n, k) each of the (n, V, 3) bodies' closed spectrum, one process per solve."""
    with ProcessPoolExecutor(workers) as pool:
        return np.stack(list(pool.map(closed_spectrum, bodies, [faces] * len(bodies), [k] * len(bodies))))


def rebuilt_spectra(models: SpectralModels, spectra: np.ndarray, sigma: np.ndarray) -> np.ndarray:
    """(n, k) the closed spectrum of the body the served decoder rebuilds from each row (with its σ):
    what ``/v1/reconstruct`` checks its answer by and ``/v1/retrieve`` ranks an open union by."""
    bodies = np.stack([models.reconstruct(s, z) for s, z in zip(spectra, sigma, strict=True)])
    return closed_spectra(bodies, models.template.faces, models.k)


def round_trip(bodies: np.ndarray, faces: np.ndarray, targets: np.ndarray, workers: int | None) -> dict[str, float]:
    """The rebuilt bodies' own spectra against the spectra they were decoded from (λ₂…λ_k): the
    mean gap, and its 5th and 95th percentiles (what ``/v1/reconstruct``'s verdict thresholds
    are read against)."""
    spectra = closed_spectra(bodies, faces, targets.shape[1], workers)
    gaps = [spectrum_gap(s, t) for s, t in zip(spectra, targets, strict=True)]
    low, high = np.percentile(gaps, [5, 95])
    return {"spectrum_mre": float(np.mean(gaps)), "spectrum_p05": float(low), "spectrum_p95": float(high)}


def identity_groups(data: SpectralData) -> np.ndarray:
    """The group (known_man, …, child) of each of the benchmark's identities."""
    return np.array([i["group"] for i in json.loads((data.root / "work" / "identities.json").read_text())])


def chained_union(views: np.ndarray, union: Union) -> tuple[np.ndarray, np.ndarray]:
    """(spectra, σ) of the union of each row's views (rows, views, k), folded left to right with σ
    carried as the service carries it (:func:`app.inference.models.chained_sigma`)."""
    current, sigma = views[:, 0], np.zeros_like(views[:, 0])
    for view in range(1, views.shape[1]):
        step, step_sigma = union(current, views[:, view])
        sigma = chained_sigma(current, sigma, step, step_sigma)
        current = step
    return current, sigma


def query_sets(data: SpectralData, union: Union) -> dict[str, Queries]:
    """The queries of each set (a), (b), (c) of the module docstring."""
    unknown = np.flatnonzero(np.isin(identity_groups(data), UNKNOWN_GROUPS))
    shapes, spectra = data.complete_spectra()
    keep = np.isin(data.identity_of(shapes), unknown)
    measured = spectra[keep]
    sets = {"true_spectrum": (measured, np.zeros_like(measured), data.identity_of(shapes[keep]))}
    pairs = data.pairs
    chosen = pairs.rows(
        np.flatnonzero(
            (pairs.split == "test_a") & (pairs.scenario == "full") & (pairs.variant == MESH)
            & np.isin(pairs.group, UNKNOWN_GROUPS)
        )
    )  # fmt: skip
    sets["two_part_union"] = (*union(chosen.a, chosen.b), data.identity_of(chosen.shape_a))
    chains = data.chains
    sets["session_chain"] = (*chained_union(chains.views, union), data.identity_of(chains.shape))
    exact = chains.unions[:, -1].astype(np.float64)
    sets["session_spectrum"] = (exact, np.zeros_like(exact), data.identity_of(chains.shape))
    scans, scanned = blind_spot_spectra(data, shapes[keep], 1, BLIND_SPOT_SEED, spectra.shape[1])
    sets["blind_spots"] = (scans, np.zeros_like(scans), data.identity_of(scanned))
    return sets


def evaluate_decoder(
    data: SpectralData,
    decode: Decoder,
    union: Union,
    mean_body: np.ndarray,
    reference: tuple[np.ndarray, np.ndarray],
    rest: np.ndarray,
    workers: int | None = None,
) -> dict:
    """Scores of the decoder and both baselines on every query set.

    ``reference`` is the nearest-identity baseline's library, (spectra (m, k), bodies (m, V, 3)):
    the decoder's training bodies in every pose. ``rest`` is the benchmark's identities' rest bodies.
    """
    faces = data.template.faces
    library = features(reference[0])
    table = {}
    for name, (spectra, sigma, identity) in query_sets(data, union).items():
        truth = rest[identity]
        decoded = decode(spectra, sigma)
        nearest = np.argmin(((features(spectra)[:, None] - library[None]) ** 2).sum(-1), axis=1)
        table[name] = {
            "queries": len(spectra),
            "identities": int(len(np.unique(identity))),
            "decoder": {**body_scores(decoded, truth, faces), **round_trip(decoded, faces, spectra, workers)},
            "mean_body": body_scores(np.repeat(mean_body[None], len(truth), 0), truth, faces),
            "nearest_identity": body_scores(reference[1][nearest], truth, faces),
        }
    return table
