"""The shape basis and the decoder graph: exact on their span, and the same in ONNX."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxscript")

from app.contract import RECONSTRUCTION_INPUTS  # noqa: E402
from training.common.onnx_export import session  # noqa: E402
from training.reconstruction.decoder import (  # noqa: E402
    DecoderConfig,
    ShapeBasis,
    SpectrumDecoder,
    SpectrumNetwork,
)
from training.reconstruction.export import decoder_parity, export_decoder  # noqa: E402


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


def _decoder(bodies: np.ndarray, k: int = 20) -> SpectrumDecoder:
    torch.manual_seed(0)
    config = DecoderConfig(k=k, components=3, width=16)
    measured, predicted = (SpectrumNetwork(config, np.zeros(k - 1), np.ones(k - 1)) for _ in range(2))
    return SpectrumDecoder(config, ShapeBasis.fit(bodies, 3), measured, predicted).eval()


def _spectra(count: int, k: int = 20) -> np.ndarray:
    spectra = np.sort(np.random.default_rng(1).uniform(0.5, 60, (count, k)), axis=1)
    spectra[:, 0] = 0.0  # a closed body's λ₁
    return spectra


def test_the_exported_decoder_matches_pytorch_at_any_batch_size(bodies, tmp_path):
    model = _decoder(bodies)
    export_decoder(model, tmp_path / "decoder.onnx")
    spectra = _spectra(5)
    sigma = 0.05 * spectra * (np.arange(5) % 2)[:, None]  # measured and predicted rows
    assert decoder_parity(model, tmp_path / "decoder.onnx", spectra, sigma) < 1e-5
    shaped = model(*(torch.as_tensor(x, dtype=torch.float32) for x in (spectra, sigma)))
    assert shaped.shape == (5, 30, 3)


def test_a_measured_spectrum_is_read_by_the_measured_network_and_a_union_by_the_other(bodies, tmp_path):
    """σ all zero picks the network trained on measured spectra; any σ > 0, even one eigenvalue's,
    the union's. Checked on the exported graph, row by row in one batch."""
    model = _decoder(bodies)
    export_decoder(model, tmp_path / "decoder.onnx")
    spectra = _spectra(3).astype(np.float32)
    sigma = np.zeros_like(spectra)
    sigma[1, 7] = 0.01  # one eigenvalue predicted: a union
    sigma[2] = 0.05 * spectra[2]
    feeds = dict(zip(RECONSTRUCTION_INPUTS, (spectra, sigma), strict=True))
    (got,) = session(tmp_path / "decoder.onnx").run(None, feeds)
    with torch.no_grad():
        x = torch.as_tensor(spectra)
        measured, predicted = model.measured(x), model.predicted(x)
        expected = torch.stack([measured[0], predicted[1], predicted[2]]) @ model.components + model.mean
    np.testing.assert_allclose(got.reshape(3, -1), expected.numpy(), rtol=1e-5, atol=1e-6)
    assert not np.allclose(model.measured(x).detach().numpy(), model.predicted(x).detach().numpy())


def test_a_measured_spectrum_of_a_surface_with_a_boundary_is_read_by_the_union_network(bodies, tmp_path):
    """λ₁ > 0 is a boundary: one partial scan is no complete body, whatever its σ. Rows: closed
    (λ₁ = 0), λ₁ at 0.1 % of λ₂ (solver noise, still closed), and at 20 % (a hole)."""
    model = _decoder(bodies)
    export_decoder(model, tmp_path / "decoder.onnx")
    spectra = np.repeat(_spectra(1), 3, 0).astype(np.float32)
    spectra[1, 0], spectra[2, 0] = 1e-3 * spectra[1, 1], 0.2 * spectra[2, 1]
    feeds = dict(zip(RECONSTRUCTION_INPUTS, (spectra, np.zeros_like(spectra)), strict=True))
    (got,) = session(tmp_path / "decoder.onnx").run(None, feeds)
    with torch.no_grad():
        x = torch.as_tensor(spectra)  # the networks read λ₂…λ_k: the same row to both
        measured, predicted = model.measured(x), model.predicted(x)
        expected = torch.stack([measured[0], measured[1], predicted[2]]) @ model.components + model.mean
    np.testing.assert_allclose(got.reshape(3, -1), expected.numpy(), rtol=1e-5, atol=1e-6)
