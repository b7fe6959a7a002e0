"""The union operator in PyTorch: commutativity, scale equivariance, monotone output, the
retrieval prior, told overlaps, the blend."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from tests.training.spectra import spectra  # noqa: E402
from tests.training.union.operators import (  # noqa: E402
    BLENDS,
    CORRECTIONS,
    PARAMETRIZATIONS,
    READS,
    operator,
    told,
    told_overlaps,
)
from training.union.config import PRIOR, UnionConfig  # noqa: E402
from training.union.memory import EPSILON, UnionMemory, common_scale, relative_log  # noqa: E402
from training.union.net import UnionOperator  # noqa: E402


@pytest.mark.parametrize("correction", CORRECTIONS)
def test_an_untrained_operator_returns_the_prior(correction):
    """The correction starts at zero: before training, the operator is the nearest-pair lookup."""
    a, b, union = spectra(30, 16), spectra(30, 17), spectra(30, 18)
    config = UnionConfig(correction=correction, parametrization=PRIOR)
    model = UnionOperator(config, UnionMemory(a, b, union)).eval()
    with torch.no_grad():
        predicted, _ = model(b * 3, a * 3)
    torch.testing.assert_close(predicted, union * 3, rtol=1e-4, atol=1e-3)


@pytest.mark.parametrize("correction", CORRECTIONS)
def test_an_untrained_monotone_operator_returns_the_prior_below_the_minimum(correction):
    """Monotone: a prior well below min(a, b) comes back as it is; one above it is cut to it."""
    a, b = spectra(30, 16), spectra(30, 17)
    floor = torch.minimum(a, b)
    union = floor * torch.where(torch.arange(20) % 2 == 0, 0.5, 1.5)  # even indices below, odd above
    model = UnionOperator(UnionConfig(correction=correction), UnionMemory(a, b, union)).eval()
    with torch.no_grad():
        predicted, _ = model(b * 3, a * 3)
    expected = torch.sort(torch.minimum(union, floor), dim=1).values * 3
    torch.testing.assert_close(predicted, expected, rtol=1e-2, atol=1e-2)


@pytest.mark.parametrize("reads", READS)
@pytest.mark.parametrize("blend", BLENDS)
@pytest.mark.parametrize("correction", CORRECTIONS)
def test_a_monotone_union_is_never_above_either_part_whatever_its_weights(correction, blend, reads):
    """λᵢ(A ∪ B) ≤ min(λᵢ(A), λᵢ(B)) by construction: random weights, random operands."""
    for seed in range(3):
        model = operator(correction, seed, blend=blend, reads=reads)
        for name, parameter in model.correction.named_parameters():
            if "weight" in name and parameter.dim() > 1:
                torch.nn.init.normal_(parameter, std=0.5)
        a, b = spectra(64, 10 + seed), spectra(64, 20 + seed) * (0.2 + seed)
        with torch.no_grad():
            union, _ = model(a, b, None, *told(model, 64, seed))
        assert (union <= torch.minimum(a, b) * (1 + 1e-5)).all()


@pytest.mark.parametrize("reads", READS)
@pytest.mark.parametrize("blend", BLENDS)
@pytest.mark.parametrize("correction", CORRECTIONS)
def test_a_part_united_with_itself_is_itself_whatever_its_weights(correction, blend, reads):
    """Idempotence by construction: the coincidence gate is exactly 0 for one spectrum twice,
    so U(A, A) = A with random weights and a memory that knows nothing of A; two different
    parts get the full decrease the network proposes, and a pair 1 % apart stays below both."""
    a = spectra(64, 30)
    for seed in range(3):
        model = operator(correction, seed, blend=blend, reads=reads)
        for name, parameter in model.correction.named_parameters():
            if "weight" in name and parameter.dim() > 1:
                torch.nn.init.normal_(parameter, std=0.5)
        said = told(model, 64, seed)
        with torch.no_grad():
            union, _ = model(a, a, None, *said)
            jittered = a * (1 + 0.01 * torch.randn(a.shape, generator=torch.Generator().manual_seed(seed)))
            near = model(a, jittered, None, *said)
            scale = common_scale(a, a)
            za = relative_log(a, scale)
            gates = model.coincidence(za, za), model.coincidence(za, relative_log(spectra(64, 31), scale))
        torch.testing.assert_close(union, a, rtol=1e-5, atol=1e-5)
        assert (gates[0] == 0).all() and (gates[1] > 0.99).all()
        assert (near[0] <= torch.minimum(a, a) * (1 + 1e-5)).all()


@pytest.mark.parametrize("reads", READS)
@pytest.mark.parametrize("blend", BLENDS)
@pytest.mark.parametrize("parametrization", PARAMETRIZATIONS)
@pytest.mark.parametrize("correction", CORRECTIONS)
def test_union_is_exactly_commutative_and_non_decreasing(correction, parametrization, blend, reads):
    model = operator(correction, parametrization=parametrization, blend=blend, reads=reads)
    a, b = spectra(64, 1), spectra(64, 2)
    said = told(model, 64, 5)
    with torch.no_grad():
        ab, sigma_ab = model(a, b, None, *said)
        ba, sigma_ba = model(b, a, None, *said)
    assert torch.equal(ab, ba) and torch.equal(sigma_ab, sigma_ba)
    assert (torch.diff(ab, dim=1) >= 0).all() and (ab >= 0).all() and (sigma_ab > 0).all()


@pytest.mark.parametrize("reads", READS)
@pytest.mark.parametrize("blend", BLENDS)
@pytest.mark.parametrize("correction", CORRECTIONS)
@pytest.mark.parametrize("factor", [0.01, 0.25, 3.0, 1e4])
def test_union_is_scale_equivariant(factor, correction, blend, reads):
    """A body scaled by s has every eigenvalue scaled by 1/s², its unions' included. Up to float32
    rounding, relative to each value, and, for a union eigenvalue random weights push near zero,
    to the cancellation in exp(z) − ε: a few float32 ulps of ε in the common scale."""
    model = operator(correction, blend=blend, reads=reads)
    a, b = spectra(16, 3), spectra(16, 4)
    said = told(model, 16, 6)
    with torch.no_grad():
        union, sigma = model(a, b, None, *said)
        scaled_union, scaled_sigma = model(a * factor, b * factor, None, *said)
    cancellation = 1e-6 * EPSILON * float(common_scale(a, b).max()) * factor
    torch.testing.assert_close(scaled_union, union * factor, rtol=1e-5, atol=cancellation)
    torch.testing.assert_close(scaled_sigma, sigma * factor, rtol=1e-5, atol=0)


@pytest.mark.parametrize("correction", CORRECTIONS)
def test_union_keeps_the_relative_size_of_the_parts(correction):
    """The common scale is shared by both operands, never one per part: a bigger second part
    (same shape of spectrum) is a different union, not the same one rescaled."""
    model = operator(correction)
    a, b = spectra(16, 5), spectra(16, 6)
    with torch.no_grad():
        union = model(a, b)[0]
        bigger_b = model(a, b / 3)[0]
    ratio = bigger_b / union
    assert not torch.allclose(ratio, ratio[:, :1].expand_as(ratio), rtol=1e-3)


@pytest.mark.parametrize("correction", CORRECTIONS)
def test_a_told_overlap_reaches_the_union_and_an_unknown_one_is_not_told(correction):
    """An operator that reads the overlap answers differently for different told shares; told
    "unknown" (any negative value) it answers as when told nothing, without the σ factor for told
    pairs; and an operator that does not read it ignores it."""
    model = operator(correction, reads="told")
    a, b = spectra(16, 7), spectra(16, 8)
    with torch.no_grad():
        nothing = model(a, b)
        unknown = model(a, b, None, torch.full((16, 1), -0.5))
        nested, apart = (model(a, b, None, torch.full((16, 1), share))[0] for share in (1.0, 0.0))
        plain = operator(correction, reads="disjoint")
        ignored, untold = plain(a, b, None, torch.full((16, 1), 0.3)), plain(a, b)
    assert torch.equal(nothing[0], unknown[0]) and torch.equal(nothing[1], unknown[1])
    assert (nested - apart).abs().max() > 1e-3 * apart.abs().max()
    assert torch.equal(ignored[0], untold[0]) and torch.equal(ignored[1], untold[1])


def test_the_told_specialist_answers_the_told_pairs_and_only_them():
    """With a told specialist attached, pairs told their overlap get its answer (another one than
    the correction's), pairs not told get exactly the correction's; told 0 and told 1 differ."""
    alone = operator("transformer", reads="told")
    with_specialist = operator("transformer", reads="told_specialist")
    a, b = spectra(16, 11), spectra(16, 12)
    overlap = told_overlaps(16, 4)
    known = overlap[:, 0] >= 0
    with torch.no_grad():
        first, second = alone(a, b, None, overlap), with_specialist(a, b, None, overlap)
        nested, apart = (with_specialist(a, b, None, torch.full((16, 1), share))[0] for share in (1.0, 0.0))
    assert torch.equal(first[0][~known], second[0][~known]) and torch.equal(first[1][~known], second[1][~known])
    assert ((first[0][known] - second[0][known]).abs().amax(1) > 1e-4 * first[0][known].amax(1)).all()
    assert (nested - apart).abs().max() > 1e-3 * apart.abs().max()


def test_a_told_boundary_share_reaches_the_pairs_told_their_overlap_and_only_them():
    """The boundary specialist answers told 0 (the union closes) and told 1 (neither covers the
    other's boundary) differently; told it unknown (any negative value), the share's specialist
    answers, as when told nothing of it, bit for bit as an operator without a boundary specialist;
    for a pair whose overlap is not told, the boundary share changes nothing (the correction
    answers it)."""
    model = operator("transformer", reads="told_boundary")
    a, b = spectra(16, 13), spectra(16, 14)
    share = torch.full((16, 1), 0.4)
    with torch.no_grad():
        closed, open_ = (model(a, b, None, share, torch.full((16, 1), edge))[0] for edge in (0.0, 1.0))
        nothing, unknown = model(a, b, None, share), model(a, b, None, share, torch.full((16, 1), -0.5))
        untold = torch.full((16, 1), -1.0)
        ignored, plain = model(a, b, None, untold, torch.full((16, 1), 0.3)), model(a, b, None, untold)
    assert (closed - open_).abs().max() > 1e-3 * open_.abs().max()
    assert torch.equal(nothing[0], unknown[0]) and torch.equal(nothing[1], unknown[1])
    assert torch.equal(ignored[0], plain[0]) and torch.equal(ignored[1], plain[1])
    share_only = operator("transformer", reads="told_specialist")(a, b, None, share)
    assert torch.equal(share_only[0], nothing[0]) and torch.equal(share_only[1], nothing[1])


@pytest.mark.parametrize("with_chains", [False, True])
@pytest.mark.parametrize("answer", ["network", "neighbours"])
def test_the_blend_fitted_on_validation_pairs_finds_which_decrease_their_unions_follow(answer, with_chains):
    """Validation unions (and chains (A ∪ B) ∪ C) made by the network's decrease alone keep the
    blend (near) off; made by the neighbours' median decrease, the fitted blend follows it
    (w → 1): in both cases the fitted operator reproduces them far better than the other answer."""
    from training.common.spectral_errors import spectral_errors
    from training.union.blend import fit_blend
    from training.union.net import UNFITTED_BLEND

    model = operator("deepsets")
    a, b, c = spectra(400, 50), spectra(400, 51) * 0.5, spectra(400, 52) * 0.7
    bodies = (np.arange(50) + 1000, np.arange(400))  # no memory row is a validation pair's body
    answers = {}
    with torch.no_grad():
        for name, weights in (("network", UNFITTED_BLEND), ("neighbours", (30.0, 0.0, 0.0, 0.0, 0.0))):
            model.set_blend_weights(weights)  # w = 0, and w = 1 − 1e-13
            answers[name] = (model(a, b)[0], model(model(a, b)[0], c)[0])
    other_name = "neighbours" if answer == "network" else "network"
    truth, other = ([x.numpy() for x in answers[name]] for name in (answer, other_name))
    assert np.abs(truth[0] / other[0] - 1).mean() > 0.02  # the two answers differ
    chains = ((a.numpy(), b.numpy(), c.numpy(), truth[1]), np.arange(400)) if with_chains else None
    weights = fit_blend(model, a.numpy(), b.numpy(), truth[0], bodies, chains)
    assert np.allclose(model.blend_weights.numpy(), weights)
    with torch.no_grad():
        fitted = (model(a, b)[0].numpy(), model(model(a, b)[0], c)[0].numpy())
    for step in range(2 if with_chains else 1):
        error, other_error = (spectral_errors(x[step], truth[step])["mre"] for x in (fitted, other))
        assert error < 0.1 * other_error
    if answer == "network":
        assert weights[0] == UNFITTED_BLEND[0] or spectral_errors(fitted[0], truth[0])["mre"] < 1e-3


def test_the_inference_form_of_the_transformer_computes_what_training_does():
    """Outside training T_A reads both operand orders as one batch, through attention written
    out by hand (a graph a third the size); training keeps two calls through PyTorch's own. The
    two must be one function: same weights, same unions, to float32 rounding through 15 layers
    (measured: 1.5e-6 relative at most, on 7 of 1 280 eigenvalues of this random operator)."""
    model = operator("transformer")
    a, b = spectra(64, 1), spectra(64, 2)
    with torch.no_grad():
        inference = model(a, b)
        model.train()
        training = model(a, b)
    for inferred, trained in zip(inference, training, strict=True):
        np.testing.assert_allclose(inferred.numpy(), trained.numpy(), rtol=1e-5, atol=1e-6)
