"""The blend of the network's decrease with the neighbours' median one
(``UnionOperator.blended``), fitted after training on validation pairs and training chains:
five numbers, deterministic, seconds."""

from dataclasses import dataclass, fields

import numpy as np
import torch
from scipy.optimize import minimize
from scipy.special import expit

from training.common.data import SpectralData
from training.common.spectral_errors import spectral_errors
from training.union.config import MONOTONE
from training.union.memory import EPSILON
from training.union.net import UNFITTED_BLEND, UnionOperator
from training.union.predict import batches, memory_rows, predict

# The blend's search (fit_blend): Nelder–Mead from w ≈ 0.27 for every pair, a simplex of edge 2;
# with chains, refitted this many times, each time with the inner unions the last fit makes.
BLEND_START = (-1.0, 0.0, 0.0, 0.0, 0.0)
BLEND_STEP = 2.0
BLEND_CHAIN_ROUNDS = 2


@dataclass(frozen=True)
class BlendRows:
    """What the blend's fit needs of a set of pairs: the minimum and the network's decrease in z,
    the neighbours' median decrease and the weight's features (UnionOperator.blend_terms), the
    common scale, and the true unions."""

    floor: np.ndarray
    decrease: np.ndarray
    median: np.ndarray
    features: np.ndarray
    scale: np.ndarray
    union: np.ndarray

    @classmethod
    @torch.no_grad()
    def of(
        cls,
        model: UnionOperator,
        a: np.ndarray,
        b: np.ndarray,
        union: np.ndarray,
        bodies: tuple[np.ndarray, np.ndarray],
        batch: int = 1024,
    ) -> "BlendRows":
        columns: list[list[np.ndarray]] = [[] for _ in range(5)]
        for a_t, b_t, hidden, _, _ in batches(model, a, b, bodies, batch):
            parts = model.proposal(a_t, b_t, hidden)
            median, features = model.blend_terms(parts)
            values = (parts.floor, parts.decrease, median, features, parts.scale)
            for column, value in zip(columns, values, strict=True):
                column.append(value.double().cpu().numpy())
        return cls(*(np.concatenate(column) for column in columns), union=union)

    def __add__(self, other: "BlendRows") -> "BlendRows":
        return BlendRows(*(np.concatenate([getattr(self, f.name), getattr(other, f.name)]) for f in fields(self)))

    def error(self, weights: np.ndarray) -> float:
        """Mean relative error of the unions the blend with these weights makes (as the graph does)."""
        weight = expit(self.features @ weights)[:, None]
        z = self.floor - ((1 - weight) * self.decrease + weight * self.median)
        blended = np.sort(np.maximum(np.exp(z) - EPSILON, 0.0), axis=1) * self.scale
        return spectral_errors(blended, self.union)["mre"]


def training_chains(data: SpectralData) -> tuple[tuple[np.ndarray, ...], np.ndarray]:
    """The training chains as :func:`fit_blend` reads them: (A, B, C, A ∪ B ∪ C), their bodies."""
    rows = ~data.triples.test
    a, b, c, _, abc = (s[rows] for s in data.triples.spectra)
    return (a, b, c, abc), data.triples.shape[rows]


def fit_blend_on(model: UnionOperator, data: SpectralData) -> np.ndarray:
    """:func:`fit_blend` on what a run of ``data`` fits it to: its validation pairs and its training
    chains, leave-one-body-out against the memory's rows."""
    pairs = data.pairs
    validation = pairs.rows(np.flatnonzero(pairs.split == "validation"))
    bodies = (pairs.shape_a[memory_rows(data)], validation.shape_a)
    return fit_blend(model, validation.a, validation.b, validation.union, bodies, training_chains(data))


def _searched(rows: BlendRows, start: np.ndarray) -> np.ndarray:
    simplex = np.vstack([start, start + BLEND_STEP * np.eye(len(start))])
    options = {"initial_simplex": simplex, "maxiter": 3000, "xatol": 1e-3, "fatol": 1e-7}
    return minimize(rows.error, start, method="Nelder-Mead", options=options).x


def fit_blend(
    model: UnionOperator,
    a: np.ndarray,
    b: np.ndarray,
    union: np.ndarray,
    bodies: tuple[np.ndarray, np.ndarray],
    chains: tuple[tuple[np.ndarray, ...], np.ndarray] | None = None,
) -> np.ndarray:
    """Fit the weights of the blend of the network's decrease with the neighbours' median
    (``UnionOperator.blended``) to the mean relative error of the validation pairs, predicted
    leave-one-body-out, and set them. Five numbers on ~1 500 pairs, like σ's calibration.

    ``chains`` ((A, B, C, A ∪ B ∪ C) spectra, their bodies) adds the second step of chains
    (A ∪ B) ∪ C, leave-one-body-out, whose inner union is the blended operator's own (refitted
    :data:`BLEND_CHAIN_ROUNDS` times, each with the inner unions of the last fit): the service
    chains the operator, and a blend fitted on single pairs alone lost 0.6 points on the test
    chains. The weights are kept only if they beat the network alone on the rows fitted (else
    the blend stays unfitted: w = 0). Returns the weights set (the unfitted ones for the PRIOR
    parametrization, which has no decrease).
    """
    model.eval()
    model.set_blend_weights(UNFITTED_BLEND)
    unfitted = np.asarray(UNFITTED_BLEND)
    if model.config.parametrization != MONOTONE:
        return unfitted
    pairs = BlendRows.of(model, a, b, union, bodies)
    if chains is not None and not len(chains[1]):
        chains = None

    def with_chains(weights: np.ndarray) -> BlendRows:
        if chains is None:
            return pairs
        (first, second, third, truth), shapes = chains
        model.set_blend_weights(weights)
        chain_bodies = (bodies[0], shapes)
        inner = predict(model, first, second, chain_bodies)[0]
        return pairs + BlendRows.of(model, inner, third, truth, chain_bodies)

    weights = _searched(pairs, np.asarray(BLEND_START))
    for _ in range(BLEND_CHAIN_ROUNDS if chains is not None else 0):
        weights = _searched(with_chains(weights), weights)
    if with_chains(weights).error(weights) >= with_chains(unfitted).error(unfitted):
        weights = unfitted
    model.set_blend_weights(weights)
    return weights
