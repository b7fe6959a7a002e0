"""The union operator and localizer in PyTorch: commutativity, scale equivariance, monotone output, size."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from training.learning.localizer_net import Localizer, LocalizerConfig, feature_statistics  # noqa: E402
from training.learning.union_net import UnionConfig, UnionOperator, offsets  # noqa: E402


def spectra(count: int, seed: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.cumsum(torch.rand(count, 20, generator=generator) * 40, dim=1)


def test_offsets_invert_to_the_spectrum():
    x = spectra(4, 0)
    torch.testing.assert_close(torch.cumsum(offsets(x), dim=1), x)


def test_union_is_exactly_commutative_and_non_decreasing():
    model = UnionOperator(UnionConfig()).eval()
    a, b = spectra(64, 1), spectra(64, 2)
    with torch.no_grad():
        ab, sigma_ab = model(a, b)
        ba, sigma_ba = model(b, a)
    assert torch.equal(ab, ba) and torch.equal(sigma_ab, sigma_ba)
    assert (torch.diff(ab, dim=1) >= 0).all() and (ab >= 0).all() and (sigma_ab > 0).all()


@pytest.mark.parametrize("factor", [0.01, 0.25, 3.0, 1e4])
def test_union_is_scale_equivariant(factor):
    """A body scaled by s has every eigenvalue scaled by 1/s², its unions' included."""
    model = UnionOperator(UnionConfig()).eval()
    a, b = spectra(16, 3), spectra(16, 4)
    with torch.no_grad():
        union, sigma = model(a, b)
        scaled_union, scaled_sigma = model(a * factor, b * factor)
    torch.testing.assert_close(scaled_union, union * factor, rtol=1e-5, atol=0)
    torch.testing.assert_close(scaled_sigma, sigma * factor, rtol=1e-5, atol=0)


def test_union_keeps_the_relative_size_of_the_parts():
    """The common scale is shared by both operands, never one per part: a bigger second part
    (same shape of spectrum) is a different union, not the same one rescaled."""
    model = UnionOperator(UnionConfig()).eval()
    a, b = spectra(16, 5), spectra(16, 6)
    with torch.no_grad():
        union = model(a, b)[0]
        bigger_b = model(a, b / 3)[0]
    ratio = bigger_b / union
    assert not torch.allclose(ratio, ratio[:, :1].expand_as(ratio), rtol=1e-3)


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
