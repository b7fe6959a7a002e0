"""σ's calibration: the weights of σ's terms (``UnionOperator.sigma``) fitted on validation
pairs so that μ ± z·σ holds 90 % of the eigenvalues, evenly across kinds of pair; and the factor
of pairs told their overlap."""

from itertools import product

import numpy as np
import torch

from app.contract import INTERVAL_Z
from training.union.config import MONOTONE
from training.union.memory import common_scale, relative_log
from training.union.net import SIGMA_FLOOR, UnionOperator
from training.union.predict import predict, tensor

DECREASE_WEIGHTS = (0.0, 0.25, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0)  # σ's decrease term, relative to the spread's
DISAGREEMENT_WEIGHTS = (0.0, 0.5, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0)  # σ's disagreement term, relative to the spread's
# σ's term in how far apart the network's and the neighbours' decreases are, relative to the spread's:
# on the served run it outweighs the spread (256 was kept; a grid up to 16 384 kept it too).
SPLIT_WEIGHTS = (0.0, 1.0, 2.0, 4.0, 8.0, 16.0, 32.0, 64.0, 128.0, 256.0)
FLOOR_GRID = (0.01, 0.02, 0.03, 0.05, 0.08)  # σ's floor (a share of the union), when calibrated (0.01: fixed)
CALIBRATION_BINS = 5
COINCIDENT = 0.5  # a validation pair whose coincidence gate is below this is taken for one region twice
IDENTICAL_BIN, REMESHED_BIN, TWICE_BIN = -1, 0, 1  # then the quintiles of the decrease


@torch.no_grad()
def coincidence(model: UnionOperator, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """(n,) the operator's coincidence gate of each pair (1 when it has none)."""
    device = next(model.parameters()).device
    a_t, b_t = tensor(a, device), tensor(b, device)
    scale = common_scale(a_t, b_t)
    return model.coincidence(relative_log(a_t, scale), relative_log(b_t, scale))[:, 0].cpu().numpy()


def calibration_bins(
    model: UnionOperator, a: np.ndarray, b: np.ndarray, added: np.ndarray, remeshed: np.ndarray
) -> np.ndarray:
    """(n,) the bin each validation pair's coverage is checked in.

    Pairs whose parts are in another meshing than their union (``remeshed``) in
    :data:`REMESHED_BIN`, one spectrum twice among them: its union differs from it by the
    meshing alone. Of the rest, one spectrum twice is exact and in no bin
    (:data:`IDENTICAL_BIN`); pairs taken for one region scanned twice in :data:`TWICE_BIN` when
    there are enough of them; every other pair by quintiles of how much the operator says the
    parts add. A bin with too few pairs to judge a 90 % coverage by is merged into the quintiles.
    """
    gate = coincidence(model, a, b)
    identical = (a == b).all(1) & ~remeshed
    if remeshed.sum() < 2 * CALIBRATION_BINS:
        remeshed = np.zeros_like(remeshed)
    twice = (gate < COINCIDENT) & ~identical & ~remeshed
    if twice.sum() < 2 * CALIBRATION_BINS:
        twice[:] = False
    apart = ~twice & ~identical & ~remeshed
    edges = np.quantile(added[apart], np.linspace(0, 1, CALIBRATION_BINS + 1)[1:-1]) if apart.any() else []
    bins = TWICE_BIN + 1 + np.searchsorted(edges, added)
    return np.select([identical, remeshed, twice], [IDENTICAL_BIN, REMESHED_BIN, TWICE_BIN], default=bins)


def calibrate(
    model: UnionOperator,
    a: np.ndarray,
    b: np.ndarray,
    union: np.ndarray,
    remeshed: np.ndarray,
    bodies: tuple[np.ndarray, np.ndarray],
    floors: tuple[float, ...] = (SIGMA_FLOOR,),
) -> tuple[float, ...]:
    """Fit σ's five weights so that μ ± z·σ holds 90 % of the validation eigenvalues, and as
    evenly as it can across the bins of :func:`calibration_bins`: re-meshed pairs, pairs taken
    for one region scanned twice, pairs that add little and pairs that add much.

    The floor is absolute (a share of the union, of ``floors``): it stands for what meshing
    alone moves a spectrum by, which validation pairs, in the training meshing, cannot show
    unless re-meshed ones are among them (then ``floors`` is a grid to choose from). For each
    floor and each relative weight of the decrease, disagreement and split terms (the spread's
    being 1), the common factor of those terms is the one that covers 90 % overall; the weights
    kept are those whose worst coverage over the bins is nearest 90 %. Scaling the floor with
    the other terms let it shrink with the spread's share once the split term came (to 2 % of
    its value) and halved the coverage of re-meshed re-scans on the tests. ``remeshed`` flags
    the pairs whose parts are in another meshing than their union. Returns the (spread, floor,
    decrease, disagreement, split) weights.
    """
    parts = []
    for weights in np.eye(5):
        model.set_sigma_weights(*weights)
        mean, sigma = predict(model, a, b, bodies)
        parts.append(sigma)
    error = np.abs(mean - union)
    added = parts[2].mean(1) / np.maximum(np.abs(mean).mean(1), 1e-12)
    bins = calibration_bins(model, a, b, added, remeshed)
    checked = np.unique(bins[bins != IDENTICAL_BIN])
    monotone = model.config.parametrization == MONOTONE
    grid = product(
        floors,
        DECREASE_WEIGHTS if monotone else (0.0,),
        DISAGREEMENT_WEIGHTS if model.gated else (0.0,),
        SPLIT_WEIGHTS if monotone else (0.0,),
    )
    best = (np.inf, 1.0, SIGMA_FLOOR, 0.0, 0.0, 0.0)
    for floor, *relative in grid:
        terms = np.maximum(parts[0] + sum(w * part for w, part in zip(relative, parts[2:], strict=True)), 1e-12)
        # The smallest factor that covers each eigenvalue, over the floor's share: its 90 % quantile.
        needed = np.maximum(error / INTERVAL_Z - floor * parts[1], 0.0) / terms
        factor = float(np.quantile(needed, 0.9))
        covered = error <= INTERVAL_Z * (floor * parts[1] + factor * terms)
        worst = max(abs(covered[bins == i].mean() - 0.9) for i in checked)
        if worst < best[0]:
            best = (worst, factor, floor, *(factor * w for w in relative))
    model.set_sigma_weights(*best[1:])
    return best[1:]


def calibrate_told(
    model: UnionOperator,
    a: np.ndarray,
    b: np.ndarray,
    union: np.ndarray,
    overlap: np.ndarray,
    bodies: tuple[np.ndarray, np.ndarray],
    boundary: np.ndarray | None = None,
) -> float:
    """Fit σ's factor for pairs told their overlap (``sigma_told``, on every term of σ but the
    floor): the one that makes μ ± z·σ hold 90 % of the validation eigenvalues when each pair is
    told its true overlap. The other weights stay as :func:`calibrate` fitted them without it;
    told the overlap, the operator errs less and its σ, unscaled, would cover nearly every
    eigenvalue. Scaling the floor too (one factor on all of σ, 0.71) left re-meshed re-scans of
    one region covered 24 % of the time on Test C instead of 59 % untold. With ``boundary``, the
    factor of pairs told their boundary share too (``sigma_boundary``), who err less again: the
    share's factor left Test B told both covered 92–93 %. Returns the factor."""
    set_factor = model.set_sigma_told if boundary is None else model.set_sigma_boundary
    set_factor(0.0)  # σ is the floor alone
    mean, floor_only = predict(model, a, b, bodies, overlap=overlap, boundary=boundary)
    set_factor(1.0)
    _, sigma = predict(model, a, b, bodies, overlap=overlap, boundary=boundary)
    terms = np.maximum(sigma - floor_only, 1e-12)
    needed = np.maximum(np.abs(mean - union) / INTERVAL_Z - floor_only, 0.0) / terms
    factor = float(np.quantile(needed, 0.9))
    set_factor(factor)
    return factor
