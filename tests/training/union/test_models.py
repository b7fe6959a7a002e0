"""The union operator and localizer in PyTorch: commutativity, scale equivariance, monotone output,
the retrieval prior, size."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")

from training.localizer.net import Localizer, LocalizerConfig, feature_statistics  # noqa: E402
from training.union.config import MONOTONE, PRIOR, UnionConfig  # noqa: E402
from training.union.corrections import ToldCorrection  # noqa: E402
from training.union.memory import EPSILON, UnionMemory, common_scale, relative_log  # noqa: E402
from training.union.net import UnionOperator  # noqa: E402


def spectra(count: int, seed: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.cumsum(torch.rand(count, 20, generator=generator) * 40, dim=1)


CORRECTIONS = ("deepsets", "transformer")
PARAMETRIZATIONS = (PRIOR, MONOTONE)


# The blend of the network's decrease with the neighbours' (UnionOperator.blended): unfitted (w = 0),
# and weights that give every pair a weight of its own between 0 and 1.
BLENDS = (None, (0.5, -2.0, 1.0, 0.3, 4.0))
# What the correction reads beside the operands and the memory: nothing more, the operands' disjoint
# union, or that and the overlap a caller tells (random shares, a third of them unknown), the told
# pairs answered by the correction or by a told specialist (ToldCorrection) of random weights, and
# those told their boundary share too (random shares, every other one unknown) by a second one.
READS = ("plain", "disjoint", "told", "told_specialist", "told_boundary")


def told_overlaps(count: int, seed: int) -> torch.Tensor:
    """(count, 1) overlaps as callers tell them: shares in 0 … 1, every third one unknown (−1)."""
    shares = torch.rand(count, 1, generator=torch.Generator().manual_seed(seed))
    shares[::3] = -1.0
    return shares


def operator(
    correction: str,
    seed: int = 0,
    stored: int = 50,
    parametrization: str = MONOTONE,
    blend: tuple[float, ...] | None = None,
    reads: str = "plain",
) -> UnionOperator:
    """An operator with random weights (the correction's zero-initialised last layer too) over a
    random memory, its blend set to ``blend`` (unfitted for None), reading what ``reads`` says
    (a name of READS)."""
    memory = UnionMemory(spectra(stored, 100 + seed), spectra(stored, 200 + seed), spectra(stored, 300 + seed) / 2)
    torch.manual_seed(seed)
    config = UnionConfig(
        correction=correction,
        parametrization=parametrization,
        disjoint_prior=reads != "plain",
        overlap_hint=reads.startswith("told"),
    )
    model = UnionOperator(config, memory)
    last = model.correction.rho if correction == "transformer" else model.correction.head[-1]
    torch.nn.init.normal_(last.weight, std=0.05)
    if reads in ("told_specialist", "told_boundary"):
        for boundary in (False, True)[: 1 + (reads == "told_boundary")]:
            specialist = ToldCorrection(20, 16, boundary=boundary)
            for parameter in specialist.net.parameters():
                torch.nn.init.normal_(parameter, std=0.15)
            model.attach_told(specialist)
    if blend is not None:
        model.set_blend_weights(blend)
    model.set_sigma_told(0.6)
    return model.eval()


def told_boundaries(count: int, seed: int) -> torch.Tensor:
    """(count, 1) boundary shares as callers tell them: in 0 … 1, every other one unknown (−1)."""
    shares = torch.rand(count, 1, generator=torch.Generator().manual_seed(seed + 1000))
    shares[1::2] = -1.0
    return shares


def told(model: UnionOperator, count: int, seed: int) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """What a test tells ``model`` of its pairs: :func:`told_overlaps` if it reads them, and
    :func:`told_boundaries` if it reads those too."""
    overlap = told_overlaps(count, seed) if model.config.overlap_hint else None
    return overlap, told_boundaries(count, seed) if model.reads_boundary else None


def relative_logs(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    scale = common_scale(a, b)
    return relative_log(a, scale), relative_log(b, scale)


def test_memory_finds_a_stored_pair_in_either_order_and_at_any_scale():
    a, b, union = spectra(30, 10), spectra(30, 11), spectra(30, 12)
    memory = UnionMemory(a, b, union)
    for factor in (1.0, 0.05, 40.0):
        for first, second in ((a, b), (b, a)):
            prior, distance, _ = memory(first * factor, second * factor, 1)
            scale = common_scale(first * factor, second * factor)
            torch.testing.assert_close(prior[:, 0] * scale, union * factor, rtol=1e-5, atol=0)
            assert (distance < 1e-2).all()


def test_memory_returns_the_nearest_other_pairs_in_order():
    """With its own row hidden, a stored pair gets the unions of the nearest other pairs."""
    a, b, union = spectra(30, 13), spectra(30, 14), spectra(30, 15)
    memory = UnionMemory(a, b, union)
    za, zb = relative_logs(a, b)
    priors, distances, floors = memory(a, b, 3, torch.eye(30, dtype=torch.bool))
    forward = torch.cdist(torch.cat([za, zb], 1), memory.keys)
    backward = torch.cdist(torch.cat([zb, za], 1), memory.keys)
    expected, nearest = torch.minimum(forward, backward).fill_diagonal_(torch.inf).topk(3, largest=False)
    torch.testing.assert_close(priors, memory.unions[nearest])
    torch.testing.assert_close(distances, expected, rtol=1e-4, atol=1e-3)
    keys = memory.keys[nearest]
    torch.testing.assert_close(floors, torch.minimum(keys[..., :20], keys[..., 20:]))


def test_a_large_memory_finds_the_pairs_a_full_float64_search_finds():
    """400 stored pairs of nearly one spectrum twice (0.1 % apart, so either operand order may be
    the nearer, and more near neighbours than the float32 shortlist holds), each stored twice,
    among 1 600 pairs whose second part is 5× the first's eigenvalues: the neighbours and
    distances are those of a float64 search over every row in both orders (ties to the earlier
    row, by the memory's tie-break)."""
    generator = torch.Generator().manual_seed(7)

    def near(count: int) -> torch.Tensor:
        return torch.sort(spectra(1, 20) * (1 + 1e-3 * torch.randn(count, 20, generator=generator)), dim=1).values

    near_a, near_b = near(400), near(400)
    near_a[1::2], near_b[1::2] = near_a[::2], near_b[::2]  # each pair stored twice
    a, b = torch.cat([near_a, spectra(1600, 21)]), torch.cat([near_b, spectra(1600, 22) * 5])
    memory = UnionMemory(a, b, spectra(2000, 23))
    queries_a, queries_b = torch.cat([near(40), b[400::100]]), torch.cat([near(40), a[400::100] * 1.0001])
    forward = memory.queries(queries_a, queries_b)
    backward = torch.cat([forward[:, 20:], forward[:, :20]], dim=1)
    keys = memory.keys.double().T
    every_row = torch.minimum(memory.key_norms - 2 * forward @ keys, memory.key_norms - 2 * backward @ keys)
    expected, rows = (every_row + memory.tie_break).topk(5, largest=False)
    query_norm = (forward**2).sum(1, keepdim=True)
    priors, distances, _ = memory(queries_a, queries_b, 5)
    torch.testing.assert_close(priors, memory.unions[rows], rtol=0, atol=0)
    torch.testing.assert_close(distances, (expected + query_norm).sqrt().float())


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
