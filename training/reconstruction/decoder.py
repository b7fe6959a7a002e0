"""Spectrum → body: a linear shape basis of rest-pose bodies and a network that reads its
coefficients off a complete spectrum.

anny's bodies vary along a few phenotype axes, so a PCA of their rest-pose vertices on the
template's topology reproduces unseen bodies to a fraction of a millimetre with a few tens of
components (the card has the curve). The network maps the spectrum's scale-carrying log
eigenvalues (λ₂…λ_k; λ₁ of a closed body is 0) to those coefficients; the basis is part of the
graph, so the service gets vertices from one ONNX call and needs neither torch nor anny.

Two networks share the basis, and σ (the graph's second input) picks one per row: a measured
spectrum (σ = 0: one complete scan) goes to a network trained on measured spectra alone, a
predicted union (σ > 0) to one trained on the operator's unions as well. One network for both
has to compromise: trained on both kinds, it rebuilt measured bodies at 4.0 mm where one trained
on measured spectra alone gets 2.9, and the latter rebuilt two-part unions at 16 mm instead of 11.
Fed σ as an input instead, one network did no better on either (4.0 mm, 14.7 mm; model card).
A measured spectrum of a surface with a boundary (one partial scan, or several merged: λ₁ > 0)
is no complete body's either, and goes to the union network too, which learned partial unions'
true spectra: the measured network, which never saw a boundary, rebuilt a Test C session's five
views from their exact spectrum at 400 mm, the union network at 74 (model card).
"""

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor, nn

from app.contract import BOUNDARY_RATIO

FLOOR = 1e-6  # 1/m²: below any body's λ₂ (~0.5), keeps a union's near-zero λ₂ finite in log space
# BOUNDARY_RATIO: a closed body's λ₁ is 0 up to the solver (λ₁/λ₂ ≤ 3e-13 over the data set's
# 628 complete bodies); the benchmark's partial unions measure ≥ 0.085, and a hole of 0.2 % of
# the template's area (a scanner's blind spot) 0.16.


@dataclass(frozen=True)
class DecoderConfig:
    k: int = 20
    components: int = 24
    width: int = 256
    depth: int = 3

    def as_dict(self) -> dict:
        return asdict(self)


@dataclass(frozen=True)
class ShapeBasis:
    """mean (3V,), components (C, 3V) orthonormal, scales (C,) the coefficients' spread (m)."""

    mean: np.ndarray
    components: np.ndarray
    scales: np.ndarray

    @classmethod
    def fit(cls, rest: np.ndarray, components: int) -> "ShapeBasis":
        """PCA of (n, V, 3) rest-pose bodies."""
        flat = rest.reshape(len(rest), -1).astype(np.float64)
        mean = flat.mean(0)
        _, singular, rows = np.linalg.svd(flat - mean, full_matrices=False)
        return cls(mean, rows[:components], singular[:components] / np.sqrt(len(flat) - 1))

    def coefficients(self, rest: np.ndarray) -> np.ndarray:
        """(n, C) the whitened coefficients of (n, V, 3) bodies (their projection, / scales)."""
        return ((rest.reshape(len(rest), -1) - self.mean) @ self.components.T) / self.scales

    def scaled_components(self) -> np.ndarray:
        """(C, 3V) each component times its spread: what whitened coefficients multiply."""
        return self.components * self.scales[:, None]

    def bodies(self, coefficients: np.ndarray) -> np.ndarray:
        """(n, V, 3) from whitened coefficients."""
        return (self.mean + (coefficients * self.scales) @ self.components).reshape(len(coefficients), -1, 3)


def spectral_features(spectra: Tensor) -> Tensor:
    """log λ₂…λ_k: what of a complete spectrum is not the closed body's zero λ₁."""
    return torch.log(torch.clamp(spectra[:, 1:], min=FLOOR))


class SpectrumNetwork(nn.Module):
    """(batch, k) complete spectra in 1/m² → (batch, C) whitened basis coefficients."""

    def __init__(self, config: DecoderConfig, feature_mean: np.ndarray, feature_std: np.ndarray):
        super().__init__()
        self.register_buffer("feature_mean", torch.as_tensor(feature_mean, dtype=torch.float32))
        self.register_buffer("feature_std", torch.as_tensor(feature_std, dtype=torch.float32))
        layers: list[nn.Module] = []
        inputs = config.k - 1
        for _ in range(config.depth - 1):
            layers += [nn.Linear(inputs, config.width), nn.GELU()]
            inputs = config.width
        layers.append(nn.Linear(inputs, config.components))
        self.network = nn.Sequential(*layers)

    def forward(self, spectra: Tensor) -> Tensor:
        return self.network((spectral_features(spectra) - self.feature_mean) / self.feature_std)


class SpectrumDecoder(nn.Module):
    """(batch, k) complete spectra in 1/m² and their σ → (batch, V, 3) rest-pose vertices in metres.

    A row whose σ is all zero (measured) and whose λ₁ says the surface is closed is read by
    ``measured``, any other (a predicted union, or a surface with a boundary) by ``predicted``.
    """

    def __init__(self, config: DecoderConfig, basis: ShapeBasis, measured: SpectrumNetwork, predicted: SpectrumNetwork):
        super().__init__()
        self.config = config
        self.vertices = len(basis.mean) // 3
        self.register_buffer("mean", torch.as_tensor(basis.mean, dtype=torch.float32))
        # The networks work in whitened coefficients.
        self.register_buffer("components", torch.as_tensor(basis.scaled_components(), dtype=torch.float32))
        self.measured, self.predicted = measured, predicted

    def coefficients(self, spectra: Tensor, sigma: Tensor) -> Tensor:
        """(batch, C) whitened basis coefficients, each row from the network for its kind."""
        closed = spectra[:, :1] <= BOUNDARY_RATIO * spectra[:, 1:2]
        is_measured = (sigma == 0).all(-1, keepdim=True) & closed
        return torch.where(is_measured, self.measured(spectra), self.predicted(spectra))

    def forward(self, spectra: Tensor, sigma: Tensor) -> Tensor:
        flat = self.mean + self.coefficients(spectra, sigma) @ self.components
        return flat.reshape(-1, self.vertices, 3)  # the batch left free: a dynamic axis in ONNX
