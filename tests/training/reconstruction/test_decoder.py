"""The shape basis and the decoder graph: exact on their span, and the same in ONNX."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxscript")

from training.learning.export import decoder_parity, export_decoder  # noqa: E402
from training.reconstruction.decoder import DecoderConfig, ShapeBasis, SpectrumDecoder  # noqa: E402


@pytest.fixture
def bodies() -> np.ndarray:
    """40 bodies of 30 vertices that vary along exactly three directions."""
    rng = np.random.default_rng(0)
    mean = rng.normal(size=(30, 3))
    directions = rng.normal(size=(3, 30, 3))
    weights = rng.normal(size=(40, 3))
    return mean + np.einsum("nc,cvd->nvd", weights, directions)


def test_a_basis_as_large_as_the_span_reproduces_every_body(bodies):
    basis = ShapeBasis.fit(bodies, 3)
    np.testing.assert_allclose(basis.bodies(basis.coefficients(bodies)), bodies, atol=1e-10)


def test_whitened_coefficients_have_unit_spread_on_the_bodies_fitted(bodies):
    coefficients = ShapeBasis.fit(bodies, 3).coefficients(bodies)
    np.testing.assert_allclose(coefficients.std(0, ddof=1), 1.0, rtol=1e-10)
    np.testing.assert_allclose(coefficients.mean(0), 0.0, atol=1e-10)


def test_the_exported_decoder_matches_pytorch_at_any_batch_size(bodies, tmp_path):
    torch.manual_seed(0)
    k = 20
    model = SpectrumDecoder(
        DecoderConfig(k=k, components=3, width=16), ShapeBasis.fit(bodies, 3), np.zeros(k - 1), np.ones(k - 1)
    )
    export_decoder(model, tmp_path / "decoder.onnx")
    spectra = np.sort(np.random.default_rng(1).uniform(0.5, 60, (5, k)), axis=1)
    spectra[:, 0] = 0.0  # a closed body's λ₁
    assert decoder_parity(model, tmp_path / "decoder.onnx", spectra) < 1e-5
    assert model(torch.as_tensor(spectra, dtype=torch.float32)).shape == (5, 30, 3)
