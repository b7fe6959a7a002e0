"""Spectrum → body: a linear shape basis of rest-pose bodies and a network that reads its
coefficients off a complete spectrum.

anny's bodies vary along a few phenotype axes, so a PCA of their rest-pose vertices on the
template's topology reproduces unseen bodies to a fraction of a millimetre with a few tens of
components (the card has the curve). The network maps the spectrum's scale-carrying log
eigenvalues (λ₂…λ_k; λ₁ of a closed body is 0) to those coefficients; the basis is part of the
graph, so the service gets vertices from one ONNX call and needs neither torch nor anny.
"""

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import Tensor, nn

FLOOR = 1e-6  # 1/m²: below any body's λ₂ (~0.5), keeps a union's near-zero λ₂ finite in log space


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

    def bodies(self, coefficients: np.ndarray) -> np.ndarray:
        """(n, V, 3) from whitened coefficients."""
        return (self.mean + (coefficients * self.scales) @ self.components).reshape(len(coefficients), -1, 3)


def spectral_features(spectra: Tensor) -> Tensor:
    """log λ₂…λ_k: what of a complete spectrum is not the closed body's zero λ₁."""
    return torch.log(torch.clamp(spectra[:, 1:], min=FLOOR))


class SpectrumDecoder(nn.Module):
    """(batch, k) complete spectra in 1/m² → (batch, V, 3) rest-pose vertices in metres."""

    def __init__(self, config: DecoderConfig, basis: ShapeBasis, feature_mean: np.ndarray, feature_std: np.ndarray):
        super().__init__()
        self.config = config
        self.register_buffer("feature_mean", torch.as_tensor(feature_mean, dtype=torch.float32))
        self.register_buffer("feature_std", torch.as_tensor(feature_std, dtype=torch.float32))
        self.vertices = len(basis.mean) // 3
        self.register_buffer("mean", torch.as_tensor(basis.mean, dtype=torch.float32))
        # Each component pre-multiplied by its spread: the network works in whitened coefficients.
        scaled = basis.components * basis.scales[:, None]
        self.register_buffer("components", torch.as_tensor(scaled, dtype=torch.float32))
        layers: list[nn.Module] = []
        inputs = config.k - 1
        for _ in range(config.depth - 1):
            layers += [nn.Linear(inputs, config.width), nn.GELU()]
            inputs = config.width
        layers.append(nn.Linear(inputs, config.components))
        self.network = nn.Sequential(*layers)

    def coefficients(self, spectra: Tensor) -> Tensor:
        """(batch, C) whitened basis coefficients."""
        return self.network((spectral_features(spectra) - self.feature_mean) / self.feature_std)

    def forward(self, spectra: Tensor) -> Tensor:
        flat = self.mean + self.coefficients(spectra) @ self.components
        return flat.reshape(-1, self.vertices, 3)  # the batch left free: a dynamic axis in ONNX
