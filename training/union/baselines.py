"""Honest baselines for the union spectrum, computed in the same run as the operator.

- ``elementwise_min``: domain monotonicity says λᵢ(A ∪ B) ≤ min(λᵢ(A), λᵢ(B)); the minimum is the
  tightest bound that needs no learning.
- ``disjoint_union``: the k smallest of both spectra together, the exact union of two parts that
  share nothing (the far end of the overlap range, where the minimum is the near end).
- ``larger_part``: the spectrum of the part with the larger area (what you get by ignoring the
  smaller scan).
- :class:`UnionLookup`: the nearest training pair, matched on log-eigenvalues with the mean
  removed (shape of the spectrum, not its scale), whose union is rescaled by the mean difference.
  With few fixed region types this lookup beat every trained model, so it is the bar to clear.
"""

import numpy as np

TINY = 1e-9


def elementwise_min(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.minimum(a, b)


def disjoint_union(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    return np.sort(np.concatenate([a, b], axis=1), axis=1)[:, : a.shape[1]]


def larger_part(a: np.ndarray, b: np.ndarray, area_a: np.ndarray, area_b: np.ndarray) -> np.ndarray:
    return np.where((area_a >= area_b)[:, None], a, b)


def _centred_logs(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    logs = np.log(np.clip(np.concatenate([a, b], axis=1), TINY, None))
    mean = logs.mean(axis=1, keepdims=True)
    return logs - mean, mean[:, 0]


class UnionLookup:
    """Nearest-neighbour union of the training pairs (both operand orders, so it commutes)."""

    def __init__(self, a: np.ndarray, b: np.ndarray, union: np.ndarray) -> None:
        forward, mean = _centred_logs(a, b)
        backward, _ = _centred_logs(b, a)
        self.keys = np.concatenate([forward, backward]).astype(np.float32)
        self.means = np.concatenate([mean, mean])
        self.unions = np.concatenate([union, union])

    def predict(self, a: np.ndarray, b: np.ndarray, chunk: int = 512) -> np.ndarray:
        queries, means = _centred_logs(a, b)
        squared_keys = (self.keys**2).sum(1)
        out = np.empty_like(a, dtype=np.float64)
        for start in range(0, len(a), chunk):
            q = queries[start : start + chunk].astype(np.float32)
            distance = squared_keys[None, :] - 2 * q @ self.keys.T
            nearest = distance.argmin(axis=1)
            # Log-eigenvalues shifted by Δ mean means eigenvalues scaled by exp(Δ mean).
            factor = np.exp(means[start : start + chunk] - self.means[nearest])
            out[start : start + chunk] = self.unions[nearest] * factor[:, None]
        return out
