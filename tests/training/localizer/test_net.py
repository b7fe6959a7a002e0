"""The spectral localizer's network: its basis head is small and maps a spectrum to vertices."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.training.spectra import spectra  # noqa: E402
from training.localizer.net import Localizer, LocalizerConfig, feature_statistics  # noqa: E402


def test_localizer_basis_head_is_small_and_maps_to_vertices():
    n = 5000
    basis = np.linalg.qr(np.random.default_rng(0).standard_normal((n, 100)))[0]
    mean, std = feature_statistics(spectra(32, 5).numpy())
    model = Localizer(LocalizerConfig(), basis, mean, std).eval()
    with torch.no_grad():
        probability = model(spectra(3, 6))
    assert probability.shape == (3, n) and ((probability >= 0) & (probability <= 1)).all()
    trainable = sum(p.numel() for p in model.parameters())
    assert trainable < 1_000_000  # the paper's head alone is ~36 M weights
