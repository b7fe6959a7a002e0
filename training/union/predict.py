"""An operator run over numpy pairs: batched, on the model's device, in eval mode, each query
optionally hidden the memory rows cut from its own body (leave-one-body-out), as every fit after
training and every evaluation predicts."""

from collections.abc import Iterator

import numpy as np
import torch

from training.common.data import PairTable, SpectralData
from training.union.config import UnionConfig
from training.union.memory import UnionMemory
from training.union.net import UnionOperator


def tensor(array: np.ndarray, device: torch.device) -> torch.Tensor:
    return torch.as_tensor(array, dtype=torch.float32, device=device)


def memory_rows(data: SpectralData) -> np.ndarray:
    """The pair rows the operator's memory holds, in memory order: the training split."""
    return np.flatnonzero(data.pairs.split == "train")


def same_body(memory_bodies: torch.Tensor, bodies: torch.Tensor) -> torch.Tensor:
    """(B, rows) which memory rows are cut from each query's body (shape A's index)."""
    return memory_bodies[None, :] == bodies[:, None]


def build_operator(train: PairTable, config: UnionConfig) -> UnionOperator:
    """An untrained operator whose memory holds these training pairs."""
    return UnionOperator(config, UnionMemory(train.a, train.b, train.union))


@torch.no_grad()
def batches(
    model: UnionOperator,
    a: np.ndarray,
    b: np.ndarray,
    bodies: tuple[np.ndarray, np.ndarray] | None,
    batch: int,
    overlap: np.ndarray | None = None,
    boundary: np.ndarray | None = None,
) -> Iterator[tuple[torch.Tensor, torch.Tensor, torch.Tensor | None, torch.Tensor | None, torch.Tensor | None]]:
    """(a, b, the memory rows hidden from each query, the overlaps told, the boundary shares told)
    of each batch, as tensors on the model's device."""
    device = next(model.parameters()).device
    memory_bodies = None if bodies is None else torch.as_tensor(bodies[0], device=device)
    for start in range(0, len(a), batch):
        window = slice(start, start + batch)
        hidden = None
        if memory_bodies is not None:
            hidden = same_body(memory_bodies, torch.as_tensor(bodies[1][window], device=device))
        told, edge = (None if x is None else tensor(x[window], device).reshape(-1, 1) for x in (overlap, boundary))
        yield tensor(a[window], device), tensor(b[window], device), hidden, told, edge


@torch.no_grad()
def predict(
    model: UnionOperator,
    a: np.ndarray,
    b: np.ndarray,
    bodies: tuple[np.ndarray, np.ndarray] | None = None,
    batch: int = 1024,
    overlap: np.ndarray | None = None,
    boundary: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(union, σ) for numpy operands, in eval mode, on the model's device.

    ``bodies`` (the memory rows' bodies, the queries' bodies) hides from each query the memory
    rows cut from its body: predictions of training or validation pairs are then those of a new
    body, like the test pairs'. ``overlap`` (n,): what each pair is told of its overlap
    (UnionConfig.overlap_hint; negative: unknown; None: unknown for all); ``boundary`` (n,) the
    boundary shares told besides it (UnionConfig.told_boundary; negative or None: unknown).
    """
    model.eval()
    means, sigmas = [], []
    for a_t, b_t, hidden, told, edge in batches(model, a, b, bodies, batch, overlap, boundary):
        mean, sigma = model(a_t, b_t, hidden, told, edge)
        means.append(mean.cpu().numpy())
        sigmas.append(sigma.cpu().numpy())
    return np.concatenate(means), np.concatenate(sigmas)
