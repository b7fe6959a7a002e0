"""The spectral union operator: a retrieval prior corrected by a commutative network.

Two part spectra do not pin down the union (how much do the parts overlap?), and what decides
it best is experience: the union of the most similar training pair, rescaled, is already a
better union than the paper's transformer learned to predict on our data (validation mean
relative error 7.8 % against 14.2 % at the same budget, and the transformer underfits: train
13.2 %). So the operator carries its training pairs inside the model (:class:`UnionMemory`,
exported as constants of the ONNX graph, so the service needs nothing else) and learns only
the correction of those priors. The correction is a DeepSets network: one encoder φ reads each operand with the
unions of the few nearest pairs, the two codes are summed (exactly commutative, as IEEE
addition is), and a head ρ, which also sees how far those pairs are, returns the change of
every log-eigenvalue of the nearest union. σ is the spread of the retrieved unions around the
prediction, calibrated on validation data. It is trained
leave-one-out, each training pair seeing the prior of its nearest *other* pair, as a new pair
would.

Everything is in one common scale s, the mean of all 2k input eigenvalues, so the network sees
the two parts' sizes relative to each other (never each part normalised on its own):
z(λ) = log(λ / s + ε). The union comes back as s · (exp z − ε), which makes the operator exactly
scale-equivariant, as the true union is (a body scaled by c has every eigenvalue, its unions'
included, scaled by 1/c²). The output is sorted, so it is non-decreasing by construction.
"""

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn

EPSILON = 1e-3  # keeps the zero λ₁ of a closed (full-body) union finite in log space
SIGMA_FLOOR = 1e-2  # the smallest relative σ (the pose noise floor is ~2 %)


@dataclass(frozen=True)
class UnionConfig:
    k: int = 20
    neighbours: int = 4
    width: int = 256
    dropout: float = 0.0

    def as_dict(self) -> dict:
        return asdict(self)


def common_scale(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(B, 1): the mean eigenvalue of both operands, symmetric in them."""
    return torch.clamp((a.mean(-1, keepdim=True) + b.mean(-1, keepdim=True)) / 2, min=1e-6)


def relative_log(spectrum: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """z(λ) = log(λ / s + ε): scale-free, and finite for a zero eigenvalue."""
    return torch.log(torch.clamp(spectrum, min=0) / scale + EPSILON)


class UnionMemory(nn.Module):
    """The training pairs, searchable by their spectra: the operator's prior.

    A key is (z(a), z(b)) of a pair, a value its union divided by the pair's scale. A query is
    matched in both operand orders and the nearer is taken, so the prior commutes exactly and
    each pair is stored once. ``exclude`` (training only) hides one memory row per query, the
    query's own pair.
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, union: np.ndarray) -> None:
        super().__init__()
        a_t, b_t, union_t = (torch.as_tensor(x, dtype=torch.float32) for x in (a, b, union))
        scale = common_scale(a_t, b_t)
        keys = torch.cat([relative_log(a_t, scale), relative_log(b_t, scale)], dim=1)
        self.register_buffer("keys", keys)
        self.register_buffer("key_norms", (keys**2).sum(1))
        self.register_buffer("unions", union_t / scale)

    def forward(
        self, za: torch.Tensor, zb: torch.Tensor, count: int, exclude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """The ``count`` nearest pairs' unions (B, count, k), in the queries' scale, nearest
        first, and their key distances (B, count), from the queries' relative logs."""
        forward = self.key_norms - 2 * torch.cat([za, zb], dim=1) @ self.keys.T
        backward = self.key_norms - 2 * torch.cat([zb, za], dim=1) @ self.keys.T
        distance = torch.minimum(forward, backward)
        if exclude is not None:
            distance = distance.scatter(1, exclude[:, None], torch.inf)
        nearest, rows = torch.topk(distance, count, dim=1, largest=False)
        # The query's own norm, summed per operand so that both orders give the same bits.
        query_norm = (za**2).sum(1, keepdim=True) + (zb**2).sum(1, keepdim=True)
        return self.unions[rows], torch.sqrt(torch.clamp(nearest + query_norm, min=1e-8))  # finite gradient at 0


def _mlp(inputs: int, width: int, outputs: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(inputs, width), nn.GELU(), nn.Dropout(dropout), nn.Linear(width, width), nn.GELU(),
        nn.Linear(width, outputs),
    )  # fmt: skip


class UnionOperator(nn.Module):
    """(λ(A), λ(B)) → (λ(A ∪ B), σ), both (B, k) in 1/m²."""

    def __init__(self, config: UnionConfig, memory: UnionMemory) -> None:
        super().__init__()
        self.config = config
        k, n, width = config.k, config.neighbours, config.width
        self.memory = memory
        self.part = _mlp(k + n * k, width, width, config.dropout)  # φ(z(part), z(priors))
        self.head = _mlp(width + n * k + n, width, k, config.dropout)  # ρ(Σφ, z(priors), distances) → Δz
        nn.init.zeros_(self.head[-1].weight)  # start at the nearest prior
        nn.init.zeros_(self.head[-1].bias)
        # Interval calibration factor, fitted on validation data after training.
        self.register_buffer("sigma_scale", torch.ones(()))

    def forward(
        self, a: torch.Tensor, b: torch.Tensor, exclude: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        k = self.config.k
        scale = common_scale(a, b)
        za, zb = relative_log(a, scale), relative_log(b, scale)
        unions, distances = self.memory(za, zb, self.config.neighbours, exclude)
        priors = relative_log(unions, 1.0).flatten(1)
        pooled = self.part(torch.cat([za, priors], dim=1)) + self.part(torch.cat([zb, priors], dim=1))
        change = self.head(torch.cat([pooled, priors, distances], dim=1))
        union = torch.sort(torch.relu(torch.exp(priors[:, :k] + change) - EPSILON), dim=-1).values
        return union * scale, self.sigma(union, priors) * scale

    def sigma(self, union: torch.Tensor, priors: torch.Tensor) -> torch.Tensor:
        """σ relative to the common scale: how far the neighbours' unions lie from the prediction.

        The root-mean-square distance in z of the retrieved unions is a spread of plausible
        answers, scaled on validation data to a calibrated interval. A learned σ head, trained
        by Gaussian likelihood next to the mean, cost the mean a tenth of its accuracy
        (validation mae 5.1 → 5.5) and diverged on chains.
        """
        neighbours = priors.unflatten(1, (self.config.neighbours, self.config.k))
        spread = (neighbours - relative_log(union, 1.0)[:, None]).pow(2).mean(1).sqrt()
        return (spread + SIGMA_FLOOR) * (union + EPSILON) * self.sigma_scale
