"""σ of the union operator: the told pairs' factors above the floor, the calibration's 90 %,
the split term, and states saved before the floor was a weight."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.training.spectra import spectra  # noqa: E402
from tests.training.union.operators import BLENDS, CORRECTIONS, operator, told_boundaries, told_overlaps  # noqa: E402
from training.union.memory import EPSILON, common_scale  # noqa: E402


def test_sigma_of_a_pair_told_its_overlap_takes_the_told_factor_above_its_floor():
    """σ's factor for told pairs (fitted by union_sigma.calibrate_told) scales σ above its floor
    where the overlap is told, and there only; the floor (what meshing alone moves a spectrum by)
    stays whole."""
    model = operator("transformer", reads="told")
    a, b = spectra(16, 9), spectra(16, 10)
    overlap = told_overlaps(16, 3)
    with torch.no_grad():
        answers = {}
        for factor in (1.0, 0.25, 0.0):
            model.set_sigma_told(factor)
            answers[factor] = model(a, b, None, overlap)
    known = overlap[:, 0] >= 0
    union, sigma = answers[1.0]
    floor = answers[0.0][1]
    assert torch.equal(union, answers[0.25][0])
    torch.testing.assert_close(answers[0.25][1][known], floor[known] + 0.25 * (sigma[known] - floor[known]))
    torch.testing.assert_close(floor[known], model.sigma_floor * (union[known] + EPSILON * common_scale(a, b)[known]))
    assert torch.equal(answers[0.25][1][~known], sigma[~known])


def test_sigma_of_a_pair_told_its_boundary_share_takes_its_own_factor():
    """σ's factor for pairs told their boundary share too (``sigma_boundary``, fitted by
    union_sigma.calibrate_told with boundaries) scales σ above its floor there and only there:
    pairs told the share alone keep the share's factor, untold pairs none."""
    model = operator("transformer", reads="told_boundary")
    a, b = spectra(16, 16), spectra(16, 17)
    overlap, boundary = told_overlaps(16, 7), told_boundaries(16, 7)
    both = (overlap[:, 0] >= 0) & (boundary[:, 0] >= 0)
    with torch.no_grad():
        answers = {}
        for factor in (1.0, 0.25, 0.0):
            model.set_sigma_boundary(factor)
            answers[factor] = model(a, b, None, overlap, boundary)
    union, sigma = answers[1.0]
    floor = answers[0.0][1]
    assert torch.equal(union, answers[0.25][0])
    torch.testing.assert_close(answers[0.25][1][both], floor[both] + 0.25 * (sigma[both] - floor[both]))
    assert torch.equal(answers[0.25][1][~both], sigma[~both]) and torch.equal(answers[0.0][1][~both], sigma[~both])


def test_calibration_covers_ninety_percent_and_bins_pairs_by_what_makes_them_uncertain():
    """σ's weights make μ ± 1.645σ hold 90 % of the calibration eigenvalues; one spectrum twice
    is in no bin (it is exact) unless its parts are re-meshed (then its union differs by the
    meshing), re-meshed pairs have their own bin, a re-scan 1 % apart is in the one-region bin,
    different parts in the others."""
    from training.union.sigma import (
        FLOOR_GRID,
        IDENTICAL_BIN,
        REMESHED_BIN,
        TWICE_BIN,
        calibrate,
        calibration_bins,
    )

    model = operator("deepsets")
    a = spectra(300, 40)
    b = torch.cat([a[:100], a[100:200] * 1.01, spectra(100, 41)])
    with torch.no_grad():
        mean, _ = model(a, b)
    noise = 1 + 0.05 * torch.randn(mean.shape, generator=torch.Generator().manual_seed(0))
    truth = (mean * noise).numpy()
    remeshed = np.zeros(300, bool)
    remeshed[::10] = True  # ten of the identical pairs, ten re-scans, ten different pairs
    bodies = (np.arange(50) + 1000, np.arange(300))  # no memory row is a calibration pair's body
    weights = calibrate(model, a.numpy(), b.numpy(), truth, remeshed, bodies, FLOOR_GRID)
    assert len(weights) == 5 and all(w >= 0 for w in weights) and weights[0] > 0 and weights[1] > 0
    with torch.no_grad():
        mean, sigma = model(a, b)
    covered = np.abs(mean.numpy() - truth) <= 1.6449 * sigma.numpy()
    assert abs(covered.mean() - 0.9) < 0.01
    bins = calibration_bins(model, a.numpy(), b.numpy(), np.linspace(0, 1, 300), remeshed)
    assert (bins[remeshed] == REMESHED_BIN).all()
    assert (bins[:100][~remeshed[:100]] == IDENTICAL_BIN).all()
    assert (bins[100:200][~remeshed[100:200]] == TWICE_BIN).all()
    assert (bins[200:][~remeshed[200:]] > TWICE_BIN).all()
    too_few = calibration_bins(model, a.numpy(), b.numpy(), np.linspace(0, 1, 300), remeshed & (np.arange(300) < 30))
    assert not (too_few == REMESHED_BIN).any()


def test_a_state_saved_before_the_floor_was_a_weight_loads_with_the_fixed_floor_it_had():
    """Older checkpoints have no ``sigma_floor`` (theirs was SIGMA_FLOOR scaled with the spread)
    and no ``sigma_split`` (theirs was 0)."""
    from training.union.net import SIGMA_FLOOR

    saved = operator("deepsets").state_dict()
    saved["sigma_scale"] = torch.tensor(0.9)
    del saved["sigma_floor"], saved["sigma_split"]
    model = operator("deepsets")
    model.sigma_split.fill_(3.0)
    model.load_state_dict(saved)  # strict: nothing missing
    assert float(model.sigma_floor) == pytest.approx(0.9 * SIGMA_FLOOR)
    assert float(model.sigma_split) == 0.0  # the term came later: such states had none


@pytest.mark.parametrize("correction", CORRECTIONS)
def test_sigma_of_the_two_answers_split_vanishes_for_one_spectrum_twice_and_not_for_two_parts(correction):
    """σ's split term (the network's decrease against the neighbours' median) is exactly 0 for
    one spectrum twice, where both say nothing is added, and positive for different parts."""
    model = operator(correction, blend=BLENDS[1])
    model.set_sigma_weights(0.0, 0.0, 0.0, 0.0, 1.0)
    a, b = spectra(32, 60), spectra(32, 61) * 0.6
    with torch.no_grad():
        same = model(a, a)[1]
        apart = model(a, b)[1]
    assert torch.equal(same, torch.zeros_like(same))
    assert (apart.sum(1) > 0).all()
