"""The region localizer: a spectrum → a soft vertex mask on the template body.

The paper's decoder ends in a 6 890-wide dense layer (≈ 70 M parameters). Masks of body
regions are smooth at the scale of the template, so ours predicts the coefficients of the mask
in the template's first ``basis`` Laplace–Beltrami eigenfunctions (thresholding the projection of
a region on 100 of them at 0.5 keeps ~99 % area IoU, measured) and a fixed matrix turns them into
per-vertex logits. The eigenfunctions are a frozen buffer, so the network is a few hundred
thousand weights and the ONNX file a few MB, most of it the basis itself.

Input features: log(1 + λ) standardised by constants fitted once on the training spectra (not
per shape), which keeps absolute size — the localizer must know how big the region is.
"""

from dataclasses import asdict, dataclass

import numpy as np
import torch
from torch import nn


@dataclass(frozen=True)
class LocalizerConfig:
    k: int = 20
    hidden: int = 512
    layers: int = 3
    dropout: float = 0.1
    basis: int | None = 100  # None: a full per-vertex output layer (the comparison head)

    def as_dict(self) -> dict:
        return asdict(self)


class Localizer(nn.Module):
    """(B, k) eigenvalues in 1/m² → (B, n) probability that each template vertex is in the region."""

    def __init__(
        self, config: LocalizerConfig, eigenfunctions: np.ndarray, feature_mean: np.ndarray, feature_std: np.ndarray
    ) -> None:
        super().__init__()
        self.config = config
        n = eigenfunctions.shape[0]
        self.register_buffer("feature_mean", torch.as_tensor(feature_mean, dtype=torch.float32))
        self.register_buffer("feature_std", torch.as_tensor(feature_std, dtype=torch.float32))
        layers: list[nn.Module] = []
        width = config.k
        for _ in range(config.layers - 1):
            layers += [nn.Linear(width, config.hidden), nn.GELU(), nn.Dropout(config.dropout)]
            width = config.hidden
        self.body = nn.Sequential(*layers)
        if config.basis is None:
            self.head = nn.Linear(width, n)
            self.register_buffer("basis", torch.zeros(0))
        else:
            self.head = nn.Linear(width, config.basis)
            self.register_buffer("basis", torch.as_tensor(eigenfunctions[:, : config.basis].T, dtype=torch.float32))
        self.vertex_bias = nn.Parameter(torch.zeros(n))

    def logits(self, spectrum: torch.Tensor) -> torch.Tensor:
        features = (torch.log1p(spectrum.clamp_min(0)) - self.feature_mean) / self.feature_std
        out = self.head(self.body(features))
        if self.config.basis is not None:
            out = out @ self.basis
        return out + self.vertex_bias

    def forward(self, spectrum: torch.Tensor) -> torch.Tensor:
        return torch.sigmoid(self.logits(spectrum))


def feature_statistics(spectra: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Per-eigenvalue mean and std of log(1 + λ) over the training spectra."""
    features = np.log1p(np.clip(spectra, 0, None))
    return features.mean(0), features.std(0) + 1e-6
