"""The operator's memory: the training pairs, searchable by their spectra, in the pairs' common
scale and relative-log space that every part of the operator shares.

Everything is in one common scale s, the mean of all 2k input eigenvalues, so the network sees
the two parts' sizes relative to each other (never each part normalised on its own):
z(λ) = log(λ / s + ε). The union comes back as s · (exp z − ε), which makes the operator exactly
scale-equivariant, as the true union is (a body scaled by c has every eigenvalue, its unions'
included, scaled by 1/c²).
"""

import numpy as np
import torch
from torch import Tensor, nn

EPSILON = 1e-3  # keeps the zero λ₁ of a closed (full-body) union finite in log space
SHORTLIST = 128  # memory rows beyond those asked for whose float64 distance decides (UnionMemory)


def common_scale(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(B, 1): the mean eigenvalue of both operands, symmetric in them."""
    return torch.clamp((a.mean(-1, keepdim=True) + b.mean(-1, keepdim=True)) / 2, min=1e-6)


def relative_log(spectrum: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """z(λ) = log(λ / s + ε): scale-free, and finite for a zero eigenvalue."""
    return torch.log(torch.clamp(spectrum, min=0) / scale + EPSILON)


def disjoint_union(a: Tensor, b: Tensor) -> Tensor:
    """(B, k): the spectrum of A ⊔ B, two parts that share nothing and do not touch: the k
    smallest of both spectra together.

    Why: it is the analytic answer at the far end of the overlap range (the elementwise minimum
    is the other: one part inside the other), exact for disjoint parts and close for parts that
    meet along a thin band; on Test B (union types never trained on) it alone is as near the true
    union as the trained operator (model card). Never above the minimum, and symmetric bit
    for bit (the sorted values of the same 2k numbers).
    """
    return torch.sort(torch.cat([a, b], dim=1), dim=1).values[:, : a.shape[1]]


class UnionMemory(nn.Module):
    """The training pairs, searchable by their spectra: the operator's prior.

    A key is (z(a), z(b)) of a pair, a value its union divided by the pair's scale. A query is
    matched in both operand orders and the nearer is taken, so the prior commutes exactly and
    each pair is stored once. ``exclude`` (training only, (B, rows) boolean) hides memory rows
    from each query: those cut from the query's own body, its own pair and its siblings.

    The search is decided in float64: in float32 the expanded distance |k|² − 2q·k + |q|² loses
    ~1e-5 to cancellation, more than the gap between the nearest pairs of some queries, so
    PyTorch and onnxruntime (whose float32 log and matmul round differently) picked different
    neighbours for 8 of 5 100 real queries. Keys are stored in float32 (the same bits in both)
    and widened. But a float64 product with every key is slow in onnxruntime (3.7 ms per operand
    order for 28 000 keys at batch 1, where float32 takes a tenth), so float32 distances only
    shortlist :data:`SHORTLIST` more candidates than asked for (from the keys' mean, which keeps
    float32's error far below the nearest gaps), and the float64 distances of those decide: the
    same neighbours unless more than that many keys lie within float32's error of the last one
    asked for.
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, union: np.ndarray) -> None:
        super().__init__()
        a_t, b_t, union_t = (torch.as_tensor(x, dtype=torch.float64) for x in (a, b, union))
        keys = self.queries(a_t, b_t).float()
        self.register_buffer("keys", keys)
        self.register_buffer("key_norms", (keys.double() ** 2).sum(1))
        self.register_buffer("unions", (union_t / common_scale(a_t, b_t)).float())
        # Exact ties (pairs stored twice with the same spectra, e.g. a part with itself and its
        # re-scan in the rest pose) go to the earlier row in both runtimes: torch and onnxruntime
        # break top-k ties differently. Far below any real gap (≤ 3e-8 in squared distance);
        # not part of the state, so it needs no retraining.
        self.register_buffer("tie_break", torch.arange(len(keys), dtype=torch.float64) * 1e-12, persistent=False)
        # The shortlist's float32 copy, centred on the keys' mean: float32's cancellation error
        # scales with the norms, and keys lie far closer to their mean than to the origin.
        # The centred keys themselves are made in the graph (onnxruntime folds them once when it
        # loads it): stored, they would double the file's largest constant.
        centre = keys.mean(0)
        self.register_buffer("centre", centre, persistent=False)
        self.register_buffer("centred_norms", ((keys - centre) ** 2).sum(1), persistent=False)

    @staticmethod
    def queries(a: Tensor, b: Tensor) -> Tensor:
        """(z(a), z(b)) in float64, in the pair's common scale."""
        a, b = a.double(), b.double()
        scale = common_scale(a, b)
        return torch.cat([relative_log(a, scale), relative_log(b, scale)], dim=1)

    def forward(self, a: Tensor, b: Tensor, count: int, exclude: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """The ``count`` nearest pairs' unions (B, count, k) in their own common scale, nearest
        first, their key distances (B, count), and their operands' elementwise minimum in z
        (B, count, k), for operands in 1/m²."""
        k = a.shape[1]
        forward = self.queries(a, b)
        backward = torch.cat([forward[:, k:], forward[:, :k]], dim=1)
        # Squared distances from the keys' mean, the nearer operand order: float32 shortlists
        # (each order's own query norm counts here: from the mean, the two orders' differ).
        # Both orders in one product: the keys (4.5 MB) are read once, not once per order.
        centred_keys = (self.keys - self.centre).T
        centred = (torch.cat([forward, backward]) - self.centre.double()).float()
        near = (centred**2).sum(1, keepdim=True) + self.centred_norms - 2 * centred @ centred_keys
        coarse = torch.minimum(*near.unflatten(0, (2, -1)))
        if exclude is not None:
            coarse = coarse.masked_fill(exclude, torch.inf)
        candidates = torch.topk(coarse, min(count + SHORTLIST, len(self.keys)), dim=1, largest=False)[1]
        chosen = self.keys[candidates].double()  # (B, candidates, 2k)
        norms = self.key_norms[candidates]
        distance = torch.minimum(
            norms - 2 * (forward[:, None, :] * chosen).sum(-1), norms - 2 * (backward[:, None, :] * chosen).sum(-1)
        )
        distance = distance + self.tie_break[candidates]
        if exclude is not None:
            distance = distance.masked_fill(exclude.gather(1, candidates), torch.inf)
        nearest, picked = torch.topk(distance, count, dim=1, largest=False)
        rows = candidates.gather(1, picked)
        # The query's own norm, summed per operand so that both orders give the same bits.
        query_norm = (forward[:, :k] ** 2).sum(1, keepdim=True) + (forward[:, k:] ** 2).sum(1, keepdim=True)
        distances = torch.sqrt(torch.clamp(nearest + query_norm, min=1e-8))  # finite gradient at 0
        keys = self.keys[rows]
        return self.unions[rows], distances.float(), torch.minimum(keys[..., :k], keys[..., k:])
