"""A scanning session's union as the service answers it, scored on Test C's people.

Each person (:func:`training.sessions.scans.test_c_people`) is scanned in scanning order, both as
cut and re-meshed, and read every way (:mod:`training.sessions.reading`). At each length in
:data:`LENGTHS`: registered views as ``/v1/sessions`` reads them (fused), views in their own
frames as it reads them (aligned or the learned chain, as the calibration chose for that many
views; the chain where they did not align), and beside them the learned chain on its own and the
elementwise minimum of the views' spectra. Mean relative error over the k eigenvalues, and how
often each served union's 90 % interval holds the truth.
"""

import numpy as np

from app.contract import INTERVAL_Z
from app.inference import SpectralModels
from app.sessions import SessionCalibration, aligned_and_chained_sigma
from training.sessions.reading import Read, read_prefixes, session_views
from training.sessions.scans import VARIANTS, relative_error, test_c_people

LENGTHS = (2, 3, 6, 12, 24, 32)
METHODS = ("elementwise_min", "learned_chain", "unregistered", "registered")
TEST_C_STREAM = 11  # the random frames Test C's views are sent in


def evaluate_sessions(models: SpectralModels, calibration: SessionCalibration, people: int) -> dict:
    """Per session length and delivery: sessions scored, each reading's mean relative error, and
    the served unions' interval coverage."""
    sampler, found = test_c_people(people)
    faces = sampler.template.faces
    rows: dict[str, dict[str, list[float]]] = {}
    for number, person in enumerate(found):
        for variant in VARIANTS:
            views = session_views(models, person, faces, variant)
            rng = np.random.default_rng([TEST_C_STREAM, number])
            for read in read_prefixes(models, person, faces, views, LENGTHS, rng):
                row = rows.setdefault(f"{read.views}/{variant}", {})
                for name, value in _scores(calibration, read).items():
                    row.setdefault(name, []).append(value)
    return {key: _summary(row) for key, row in rows.items()}


def _scores(calibration: SessionCalibration, read: Read) -> dict[str, float]:
    by = calibration.unregistered_by(read.views)
    if by == "aligned" and read.aligned is not None:
        unregistered, sigma = read.aligned, calibration.aligned.sigma(read.aligned, read.views)
    elif by == "aligned" and read.partly is not None:
        unregistered = read.partly.eigenvalues
        sigma = aligned_and_chained_sigma(read.partly, calibration.aligned, read.views)
    else:
        unregistered, sigma = read.chain, read.chain_sigma
    fused_sigma = calibration.fused.sigma(read.fused, read.views)
    return {
        "elementwise_min": relative_error(read.elementwise_min, read.truth),
        "learned_chain": relative_error(read.chain, read.truth),
        "unregistered": relative_error(unregistered, read.truth),
        "registered": relative_error(read.fused, read.truth),
        "unregistered_held": float(np.mean(np.abs(unregistered - read.truth) <= INTERVAL_Z * sigma)),
        "registered_held": float(np.mean(np.abs(read.fused - read.truth) <= INTERVAL_Z * fused_sigma)),
        "aligned": float(by == "aligned" and (read.aligned is not None or read.partly is not None)),
    }


def _summary(row: dict[str, list[float]]) -> dict:
    return {name: round(float(np.mean(values)), 4) for name, values in row.items()} | {
        "sessions": len(row["registered"])
    }
