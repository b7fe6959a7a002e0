"""The spectral union operator: a retrieval prior corrected by a commutative network.

Two part spectra do not pin down the union (how much do the parts overlap?), and what decides
it best is experience: the union of the most similar training pair, rescaled, is already a
better union than the paper's transformer learned to predict on our data (validation mean
relative error 7.8 % against 14.2 % at the same budget, and the transformer underfits: train
13.2 %). So the operator carries its training pairs inside the model (:class:`UnionMemory`,
exported as constants of the ONNX graph, so the service needs nothing else) and learns only
the correction of those priors. The priors are of two kinds, per retrieved pair: its union,
rescaled; and what its parts added to each other (its union below its parts' elementwise
minimum, in z), taken off this pair's minimum — the one that carries "nothing added" over from
a nested or identical neighbour. The correction is the paper's pair of transformers
(:class:`TransformerCorrection`: T_A reads both operands in both orders, summed, so the
operator commutes exactly; T_B decodes), reading both kinds of prior of the few nearest pairs
and how far those pairs are, and returning the change of every log-eigenvalue of the nearest
union; :class:`DeepSetsCorrection` is the cheaper comparison. The union is then, by default
(:data:`MONOTONE`), a non-negative decrease from the operands' elementwise minimum, so that
λ(A ∪ B) ≤ min(λ(A), λ(B)) holds for every output, as it does for every true union; :data:`PRIOR`
is the unbounded corrected prior, kept for the comparison. Outside training the network's
decrease is blended with the neighbours' median one, by a per-pair weight fitted on validation
data after training (:meth:`UnionOperator.blended`). σ is the spread of the neighbours'
answers around the prediction plus a term in the predicted decrease, calibrated on validation
data. It is trained leave-one-body-out, each training pair seeing the priors of pairs cut from
other bodies, as a new pair would.

Everything is in one common scale s, the mean of all 2k input eigenvalues, so the network sees
the two parts' sizes relative to each other (never each part normalised on its own):
z(λ) = log(λ / s + ε). The union comes back as s · (exp z − ε), which makes the operator exactly
scale-equivariant, as the true union is (a body scaled by c has every eigenvalue, its unions'
included, scaled by 1/c²). The output is sorted, so it is non-decreasing by construction.
"""

import math
from dataclasses import asdict, dataclass
from typing import NamedTuple

import numpy as np
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from app.contract import UNKNOWN_OVERLAP

EPSILON = 1e-3  # keeps the zero λ₁ of a closed (full-body) union finite in log space
SIGMA_FLOOR = 1e-2  # the smallest relative σ before calibration (the pose noise floor is ~2 %)
SHORTLIST = 128  # memory rows beyond those asked for whose float64 distance decides (UnionMemory)
SHARPNESS = 20.0  # of the softplus that turns the monotone parametrization's signal into a decrease
# The coincidence gate's starting width τ in z (RMS over the spectrum): a re-scan of one region
# differs by ~1–2 % (the pose noise floor), two different parts by tens of per cent. Learned.
GATE_WIDTH = 0.03
PRIOR, MONOTONE = "prior", "monotone"  # the parametrizations of the union (UnionConfig.parametrization)
UNFITTED_BLEND = (-math.inf, 0.0, 0.0, 0.0, 0.0)  # UnionOperator.blended's weights before fitting: w = 0


@dataclass(frozen=True)
class UnionConfig:
    k: int = 20
    neighbours: int = 4
    correction: str = "transformer"  # a key of CORRECTIONS
    parametrization: str = MONOTONE  # PRIOR: the prior corrected; MONOTONE: a decrease from min(a, b)
    coincidence_gate: bool = True  # MONOTONE only: the decrease scaled by how far apart the operands are
    # The correction also reads the operands' disjoint union (:func:`disjoint_union`), the union
    # of two parts that share nothing: the other end of the overlap range from the minimum.
    disjoint_prior: bool = False
    # The operator also reads, when a caller knows it, how much of the smaller part lies inside
    # the other (``overlap``, 0 … 1; unknown when negative, UNKNOWN_OVERLAP): two part spectra do
    # not tell how much the parts overlap (benchmarks/nesting_ambiguity.py), and without it the
    # answer regresses toward the training set's typical overlap.
    overlap_hint: bool = False
    width: int = 256  # DeepSets hidden width
    # The transformers: the paper's (supplementary, "Architecture details"): T_A, which mixes the
    # two operands' tokens, 8 heads × 6 layers with a feed-forward of 64; T_B, which only
    # decodes the mixed tokens back to one value each, half as deep (3 layers, feed-forward 32).
    # Its token width is not given there; 32 (4 per head) is ours, of the size of its feed-forwards.
    embedding: int = 32
    heads: int = 8
    mixer_layers: int = 6
    mixer_feed_forward: int = 64
    decoder_layers: int = 3
    decoder_feed_forward: int = 32
    # The paper's dropout is 0.1; with the memory the correction underfits rather than overfits.
    dropout: float = 0.0
    # Width of the told specialist (ToldCorrection), the network that answers pairs told their
    # overlap; 0: none, the correction answers them too. Trained after the correction
    # (train_union.train_told), so a finished run gains one without training again.
    told_width: int = 0
    # A second told specialist answers the pairs told, besides the share, how much of the two
    # parts' boundary length is left on the union's boundary (``boundary``, 0 … 1; unknown when
    # negative, UNKNOWN_BOUNDARY). With the share it tells the union's area and boundary length,
    # the two terms of Weyl's law for a Dirichlet spectrum: a view that closes a session's holes
    # adds little area and much of the spectrum's fall, which the share alone cannot tell. A
    # network of its own, so that pairs told the share alone keep the first one's answers.
    told_boundary: bool = False

    def __post_init__(self) -> None:
        assert self.k >= 2 and self.neighbours >= 1, (self.k, self.neighbours)
        assert self.correction in CORRECTIONS, self.correction
        assert self.parametrization in (PRIOR, MONOTONE), self.parametrization
        assert self.embedding % self.heads == 0, "every head needs a whole share of the token"
        assert min(self.mixer_layers, self.decoder_layers) >= 1
        assert 0.0 <= self.dropout < 1.0

    def as_dict(self) -> dict:
        return asdict(self)

    @property
    def prior_rows(self) -> int:
        """Spectra the correction reads beside the operands: both kinds of prior per neighbour,
        the disjoint union if asked for, and the overlap hint's value and whether it is known."""
        return 2 * self.neighbours + int(self.disjoint_prior) + 2 * int(self.overlap_hint)


def overlap_rows(overlap: Tensor | None, like: Tensor) -> tuple[Tensor, Tensor]:
    """The hint as the correction reads it, (B, 2, k): its value (0 when unknown) and 1 where it
    is known, at every eigenvalue index; and ``told`` (B, 1), 1 where it is known."""
    if overlap is None:
        overlap = torch.full_like(like[:, :1], UNKNOWN_OVERLAP)
    told = (overlap >= 0).to(like.dtype)
    value = torch.clamp(overlap, min=0.0, max=1.0) * told
    return torch.stack([value.expand_as(like), told.expand_as(like)], dim=1), told


def common_scale(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """(B, 1): the mean eigenvalue of both operands, symmetric in them."""
    return torch.clamp((a.mean(-1, keepdim=True) + b.mean(-1, keepdim=True)) / 2, min=1e-6)


def relative_log(spectrum: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
    """z(λ) = log(λ / s + ε): scale-free, and finite for a zero eigenvalue."""
    return torch.log(torch.clamp(spectrum, min=0) / scale + EPSILON)


def disjoint_union(a: Tensor, b: Tensor) -> Tensor:
    """(B, k): the spectrum of A ⊔ B, two parts that share nothing and do not touch: the k
    smallest of both spectra together.

    Why: it is the analytic answer at the far end of the overlap range (the elementwise minimum
    is the other: one part inside the other), exact for disjoint parts and close for parts that
    meet along a thin band; on Test B (union types never trained on) it alone is as near the true
    union as the trained operator (model card). Never above the minimum, and symmetric bit
    for bit (the sorted values of the same 2k numbers).
    """
    return torch.sort(torch.cat([a, b], dim=1), dim=1).values[:, : a.shape[1]]


class UnionMemory(nn.Module):
    """The training pairs, searchable by their spectra: the operator's prior.

    A key is (z(a), z(b)) of a pair, a value its union divided by the pair's scale. A query is
    matched in both operand orders and the nearer is taken, so the prior commutes exactly and
    each pair is stored once. ``exclude`` (training only, (B, rows) boolean) hides memory rows
    from each query: those cut from the query's own body, its own pair and its siblings.

    The search is decided in float64: in float32 the expanded distance |k|² − 2q·k + |q|² loses
    ~1e-5 to cancellation, more than the gap between the nearest pairs of some queries, so
    PyTorch and onnxruntime (whose float32 log and matmul round differently) picked different
    neighbours for 8 of 5 100 real queries. Keys are stored in float32 (the same bits in both)
    and widened. But a float64 product with every key is slow in onnxruntime (3.7 ms per operand
    order for 28 000 keys at batch 1, where float32 takes a tenth), so float32 distances only
    shortlist :data:`SHORTLIST` more candidates than asked for (from the keys' mean, which keeps
    float32's error far below the nearest gaps), and the float64 distances of those decide: the
    same neighbours unless more than that many keys lie within float32's error of the last one
    asked for.
    """

    def __init__(self, a: np.ndarray, b: np.ndarray, union: np.ndarray) -> None:
        super().__init__()
        a_t, b_t, union_t = (torch.as_tensor(x, dtype=torch.float64) for x in (a, b, union))
        keys = self.queries(a_t, b_t).float()
        self.register_buffer("keys", keys)
        self.register_buffer("key_norms", (keys.double() ** 2).sum(1))
        self.register_buffer("unions", (union_t / common_scale(a_t, b_t)).float())
        # Exact ties (pairs stored twice with the same spectra, e.g. a part with itself and its
        # re-scan in the rest pose) go to the earlier row in both runtimes: torch and onnxruntime
        # break top-k ties differently. Far below any real gap (≤ 3e-8 in squared distance);
        # not part of the state, so it needs no retraining.
        self.register_buffer("tie_break", torch.arange(len(keys), dtype=torch.float64) * 1e-12, persistent=False)
        # The shortlist's float32 copy, centred on the keys' mean: float32's cancellation error
        # scales with the norms, and keys lie far closer to their mean than to the origin.
        # The centred keys themselves are made in the graph (onnxruntime folds them once when it
        # loads it): stored, they would double the file's largest constant.
        centre = keys.mean(0)
        self.register_buffer("centre", centre, persistent=False)
        self.register_buffer("centred_norms", ((keys - centre) ** 2).sum(1), persistent=False)

    @staticmethod
    def queries(a: Tensor, b: Tensor) -> Tensor:
        """(z(a), z(b)) in float64, in the pair's common scale."""
        a, b = a.double(), b.double()
        scale = common_scale(a, b)
        return torch.cat([relative_log(a, scale), relative_log(b, scale)], dim=1)

    def forward(self, a: Tensor, b: Tensor, count: int, exclude: Tensor | None = None) -> tuple[Tensor, Tensor, Tensor]:
        """The ``count`` nearest pairs' unions (B, count, k) in their own common scale, nearest
        first, their key distances (B, count), and their operands' elementwise minimum in z
        (B, count, k), for operands in 1/m²."""
        k = a.shape[1]
        forward = self.queries(a, b)
        backward = torch.cat([forward[:, k:], forward[:, :k]], dim=1)
        # Squared distances from the keys' mean, the nearer operand order: float32 shortlists
        # (each order's own query norm counts here: from the mean, the two orders' differ).
        # Both orders in one product: the keys (4.5 MB) are read once, not once per order.
        centred_keys = (self.keys - self.centre).T
        centred = (torch.cat([forward, backward]) - self.centre.double()).float()
        near = (centred**2).sum(1, keepdim=True) + self.centred_norms - 2 * centred @ centred_keys
        coarse = torch.minimum(*near.unflatten(0, (2, -1)))
        if exclude is not None:
            coarse = coarse.masked_fill(exclude, torch.inf)
        candidates = torch.topk(coarse, min(count + SHORTLIST, len(self.keys)), dim=1, largest=False)[1]
        chosen = self.keys[candidates].double()  # (B, candidates, 2k)
        norms = self.key_norms[candidates]
        distance = torch.minimum(
            norms - 2 * (forward[:, None, :] * chosen).sum(-1), norms - 2 * (backward[:, None, :] * chosen).sum(-1)
        )
        distance = distance + self.tie_break[candidates]
        if exclude is not None:
            distance = distance.masked_fill(exclude.gather(1, candidates), torch.inf)
        nearest, picked = torch.topk(distance, count, dim=1, largest=False)
        rows = candidates.gather(1, picked)
        # The query's own norm, summed per operand so that both orders give the same bits.
        query_norm = (forward[:, :k] ** 2).sum(1, keepdim=True) + (forward[:, k:] ** 2).sum(1, keepdim=True)
        distances = torch.sqrt(torch.clamp(nearest + query_norm, min=1e-8))  # finite gradient at 0
        keys = self.keys[rows]
        return self.unions[rows], distances.float(), torch.minimum(keys[..., :k], keys[..., k:])


def _mlp(inputs: int, width: int, outputs: int, dropout: float) -> nn.Sequential:
    return nn.Sequential(
        nn.Linear(inputs, width), nn.GELU(), nn.Dropout(dropout), nn.Linear(width, width), nn.GELU(),
        nn.Linear(width, outputs),
    )  # fmt: skip


class DeepSetsCorrection(nn.Module):
    """Δz from the operands and the priors: φ per operand, summed, then ρ.

    The sum of the two codes is what makes it commutative: IEEE addition is, bit for bit.
    """

    def __init__(self, config: UnionConfig) -> None:
        super().__init__()
        k, n, width = config.k, config.prior_rows, config.width
        self.part = _mlp(k + n * k, width, width, config.dropout)  # φ(z(part), z(priors))
        self.head = _mlp(width + n * k + config.neighbours, width, k, config.dropout)  # ρ(Σφ, priors, distances)
        nn.init.zeros_(self.head[-1].weight)  # start at the nearest prior
        nn.init.zeros_(self.head[-1].bias)

    def forward(self, za: Tensor, zb: Tensor, priors: Tensor, distances: Tensor) -> Tensor:
        flat = priors.flatten(1)
        pooled = self.part(torch.cat([za, flat], dim=1)) + self.part(torch.cat([zb, flat], dim=1))
        return self.head(torch.cat([pooled, flat, distances], dim=1))


class ToldCorrection(nn.Module):
    """The decrease in z from the operands' minimum for a pair told its overlap: an MLP reading
    both operands, their disjoint union (z, the pair's common scale) and the share told, run in
    both operand orders and averaged.

    Why a network of its own: told the share, what two parts add to each other is nearly a
    function of their spectra and that one number, and a plain MLP of three layers learns it in a
    minute and better than the transformer correction reads it as two more rows among its tokens
    (held-out rows told their share: Test B 7.5 → 6.9 %, Test C views under a quarter shared
    10.2 → 8.4 %; model card). The two orders go through the network as one batch of 2B, and the
    halves' non-negative outputs are added: commutative bit for bit, as IEEE addition is.
    """

    def __init__(self, k: int, width: int, boundary: bool = False) -> None:
        super().__init__()
        self.told_columns = 2 if boundary else 1  # the share, and the boundary share for one that reads it
        inputs = 3 * k + self.told_columns
        # The inputs' standardization, set from the training rows (set_standardization).
        self.register_buffer("centre", torch.zeros(inputs))
        self.register_buffer("spread", torch.ones(inputs))
        self.net = nn.Sequential(
            nn.Linear(inputs, width), nn.GELU(), nn.Linear(width, width), nn.GELU(),
            nn.Linear(width, width), nn.GELU(), nn.Linear(width, k),
        )  # fmt: skip

    def told(self, overlap: Tensor, boundary: Tensor | None = None) -> Tensor:
        """(B, told_columns) what the pair is told: the share and, for a specialist that reads it,
        the boundary share, each clamped to 0 … 1."""
        share = torch.clamp(overlap, min=0.0, max=1.0)
        if self.told_columns == 1:
            return share
        assert boundary is not None, "a boundary specialist answers pairs told their boundary share"
        return torch.cat([share, torch.clamp(boundary, min=0.0, max=1.0)], 1)

    @staticmethod
    def inputs(za: Tensor, zb: Tensor, disjoint: Tensor, told: Tensor) -> Tensor:
        """(2B, 3k + told columns): the pair in both operand orders, one order per half."""
        return torch.cat([torch.cat([za, zb, disjoint, told], 1), torch.cat([zb, za, disjoint, told], 1)], 0)

    @torch.no_grad()
    def set_standardization(self, inputs: Tensor) -> None:
        """Centre and spread of each input column over ``inputs`` (what is told left as it is)."""
        self.centre.copy_(inputs.mean(0))
        self.spread.copy_(inputs.std(0).clamp(min=1e-6))
        self.centre[-self.told_columns :], self.spread[-self.told_columns :] = 0.0, 1.0

    def forward(self, za: Tensor, zb: Tensor, disjoint: Tensor, told: Tensor) -> Tensor:
        """(B, k) ≥ 0: the decrease, before the coincidence gate; ``told`` from :meth:`told`."""
        both = nn.functional.softplus(self.net((self.inputs(za, zb, disjoint, told) - self.centre) / self.spread))
        half = za.shape[0]
        return (both[:half] + both[half:]) / 2


class TransformerCorrection(nn.Module):
    """Δz by the paper's two transformers, reading the priors as well.

    A token per eigenvalue index: the operand's offset in z (z_i − z_{i−1}, the paper's offset
    encoding in relative-log space), its z, the priors' z at that index, a learned position θᵢ
    and which operand it is. T_A reads both operands' tokens and returns the first operand's,
    informed by the second; it runs in both orders and the two are summed, commutative bit for
    bit. Outside training both orders go through T_A as one batch of 2B: a third fewer nodes in
    the exported graph, batch 1 ~11 % faster in onnxruntime, and the same bits as two calls (in
    PyTorch too, on every validation pair); each row is computed alike wherever it sits in the
    batch, and the halves are added as a + b. Training keeps two calls, whose weight gradients
    the served checkpoint was trained with (one batch would sum them in another order). T_B
    decodes, with the key distances added to every token, and ρ maps each token to its Δzᵢ.
    """

    def __init__(self, config: UnionConfig) -> None:
        super().__init__()
        k, d = config.k, config.embedding
        self.k = k
        self.embed = nn.Linear(2 + config.prior_rows, d)  # offset, z, and the priors
        self.position = nn.Parameter(torch.randn(k, d) * 0.02)
        self.operand = nn.Parameter(torch.randn(2, d) * 0.02)  # self, other
        self.distance = nn.Linear(config.neighbours, d)
        self.mixer = _encoder(d, config.heads, config.mixer_layers, config.mixer_feed_forward, config.dropout)  # T_A
        self.decoder = _encoder(d, config.heads, config.decoder_layers, config.decoder_feed_forward, config.dropout)
        self.rho = nn.Linear(d, 1)
        nn.init.zeros_(self.rho.weight)  # start at the nearest prior
        nn.init.zeros_(self.rho.bias)

    def _tokens(self, z: Tensor, priors: Tensor, role: int) -> Tensor:
        offsets = torch.diff(z, dim=1, prepend=torch.zeros_like(z[:, :1]))
        features = torch.cat([offsets[..., None], z[..., None], priors.transpose(1, 2)], dim=-1)
        return self.embed(features) + self.position + self.operand[role]

    def _pair_tokens(self, first: Tensor, second: Tensor, priors: Tensor) -> Tensor:
        """(B, 2k, d): the first operand's tokens, then the second's."""
        return torch.cat([self._tokens(first, priors, 0), self._tokens(second, priors, 1)], dim=1)

    def forward(self, za: Tensor, zb: Tensor, priors: Tensor, distances: Tensor) -> Tensor:
        orders = (self._pair_tokens(za, zb, priors), self._pair_tokens(zb, za, priors))
        if self.training:
            mixed = self.mixer(orders[0])[:, : self.k] + self.mixer(orders[1])[:, : self.k]
        else:
            mixed = self.mixer(torch.cat(orders, dim=0))[:, : self.k].unflatten(0, (2, -1)).sum(0)
        decoded = self.decoder(mixed + self.distance(distances)[:, None])
        return self.rho(decoded)[..., 0]


class EncoderLayer(nn.TransformerEncoderLayer):
    """PyTorch's pre-norm encoder layer whose self-attention, outside training, is ONNX's own
    ``Attention`` operator (opset 23; ``torch.onnx.ops.attention``, whose PyTorch form is its
    reference) on the in-projection's three thirds, instead of PyTorch's general multi-head
    attention.

    Why: exported, PyTorch's attention is ~40 nodes per layer of reshapes, transposes, squeezes
    and slices, and at batch 1 onnxruntime's time is per node: one ``Split`` and one
    ``Attention`` (the heads split inside the operator) leave the union graph ~200 nodes smaller
    and faster at every batch size (`benchmarks/RESULTS.md`), computing the same to float32
    rounding (`tests/training/learning/test_models.py` compares the two). Training keeps
    PyTorch's own attention, whose gradients the served checkpoint was trained with; so do
    masks, which the operator never passes.
    """

    def _sa_block(
        self, x: Tensor, attn_mask: Tensor | None, key_padding_mask: Tensor | None, is_causal: bool = False
    ) -> Tensor:
        if self.training or attn_mask is not None or key_padding_mask is not None:
            return super()._sa_block(x, attn_mask, key_padding_mask, is_causal)
        attention = self.self_attn
        heads = attention.num_heads
        q, k, v = F.linear(x, attention.in_proj_weight, attention.in_proj_bias).chunk(3, dim=-1)
        mixed = torch.onnx.ops.attention(q, k, v, q_num_heads=heads, kv_num_heads=heads)[0]
        return self.dropout1(F.linear(mixed, attention.out_proj.weight, attention.out_proj.bias))


def _encoder(width: int, heads: int, layers: int, feed_forward: int, dropout: float) -> nn.TransformerEncoder:
    layer = EncoderLayer(width, heads, feed_forward, dropout, activation="gelu", batch_first=True, norm_first=True)
    return nn.TransformerEncoder(layer, layers, enable_nested_tensor=False)


CORRECTIONS = {"deepsets": DeepSetsCorrection, "transformer": TransformerCorrection}


class Proposal(NamedTuple):
    """A pair as the operator sees it before the blend (``UnionOperator.proposal``): the common
    scale (B, 1); both operands and their minimum in z (B, k); what each neighbour's parts added
    (B, n, k) and that taken off this pair's minimum; the neighbours' key distances (B, n); the
    coincidence gate (B, 1); the corrected prior (B, k) and the network's decrease from the
    minimum (B, k; None for the PRIOR parametrization); 1 where the caller told the overlap (B, 1);
    the operands' disjoint union in z (B, k), computed once for every reader."""

    scale: Tensor
    za: Tensor
    zb: Tensor
    floor: Tensor
    added: Tensor
    transferred: Tensor
    distances: Tensor
    gate: Tensor
    proposed: Tensor
    decrease: Tensor | None
    told: Tensor
    disjoint: Tensor


def _sigma_weights_of_older_states(module: nn.Module, state: dict, prefix: str, *_: object) -> None:
    """States saved before σ's floor was a weight of its own carry none: theirs was the fixed
    SIGMA_FLOOR, scaled with the spread (σ = (spread + SIGMA_FLOOR)·sigma_scale + …). States
    saved before σ's term in the two answers' split carry no weight for it: theirs was 0."""
    key = prefix + "sigma_floor"
    if key not in state and prefix + "sigma_scale" in state:
        state[key] = SIGMA_FLOOR * state[prefix + "sigma_scale"]
    if prefix + "sigma_split" not in state and prefix + "sigma_scale" in state:
        state[prefix + "sigma_split"] = torch.zeros_like(state[prefix + "sigma_scale"])
    if prefix + "sigma_boundary" not in state and prefix + "sigma_scale" in state:  # before the boundary share
        state[prefix + "sigma_boundary"] = torch.ones_like(state[prefix + "sigma_scale"])


class UnionOperator(nn.Module):
    """(λ(A), λ(B)) → (λ(A ∪ B), σ), both (B, k) in 1/m²."""

    def __init__(self, config: UnionConfig, memory: UnionMemory) -> None:
        super().__init__()
        self.config = config
        self.memory = memory
        self.correction = CORRECTIONS[config.correction](config)
        self.gated = config.coincidence_gate and config.parametrization == MONOTONE
        if self.gated:
            self.log_gate_width = nn.Parameter(torch.tensor(math.log(GATE_WIDTH)))
        # Interval calibration weights, fitted on validation data after training.
        self.register_buffer("sigma_scale", torch.ones(()))
        self.register_buffer("sigma_floor", torch.full((), SIGMA_FLOOR))
        self.register_buffer("sigma_decrease", torch.zeros(()))
        self.register_buffer("sigma_disagreement", torch.zeros(()))
        self.register_buffer("sigma_split", torch.zeros(()))
        self.register_buffer("sigma_told", torch.ones(()))  # σ's factor where the overlap is told
        self.register_buffer("sigma_boundary", torch.ones(()))  # … where the boundary share is told too
        # The blend of the network's decrease with the neighbours' (:meth:`blended`): fitted on
        # validation pairs each time a run is loaded (deterministic, seconds), never trained, so
        # not part of the saved state; unfitted, its weight is 0.
        self.register_buffer("blend_weights", torch.tensor(UNFITTED_BLEND), persistent=False)
        self.register_load_state_dict_pre_hook(_sigma_weights_of_older_states)
        # Answers the pairs told their overlap, once trained (attach_told); None: the correction does.
        self.register_module("told_correction", None)
        # Answers the pairs told their boundary share too, once trained (attach_told); None: told_correction does.
        self.register_module("boundary_correction", None)

    def forward(
        self,
        a: Tensor,
        b: Tensor,
        exclude: Tensor | None = None,
        overlap: Tensor | None = None,
        boundary: Tensor | None = None,
    ) -> tuple[Tensor, Tensor]:
        """``overlap`` (B, 1): the share of the smaller part inside the other where a caller knows
        it, negative where not (None: unknown for all); read only with ``config.overlap_hint``.
        ``boundary`` (B, 1): the boundary share where a caller knows it besides the overlap,
        negative where not; read only by a told specialist with ``config.told_boundary``."""
        parts = self.proposal(a, b, exclude, overlap)
        boundary_read = self.reads_boundary and boundary is not None  # else the share's specialist answers
        if self.config.parametrization == MONOTONE:
            median, features = self.blend_terms(parts)
            split = (parts.decrease - median).abs()  # the network's and the neighbours' answers apart
            if self.training:
                decrease = parts.decrease
            else:
                decrease = self.blended(parts.decrease, median, features, parts.told)
            if self.told_correction is not None and overlap is not None:
                told = self.told_decrease(parts, overlap, self.told_correction)
                if boundary_read:
                    with_boundary = self.told_decrease(parts, overlap, self.boundary_correction, boundary)
                    told = torch.where(boundary >= 0, with_boundary, told)
                decrease = torch.where(parts.told > 0, told, decrease)
            z = parts.floor - decrease
        else:
            z, decrease = parts.proposed, torch.zeros_like(parts.proposed)
            split = decrease
        union = torch.sort(torch.relu(torch.exp(z) - EPSILON), dim=-1).values
        disagreement = (1 - parts.gate) * (parts.za - parts.zb).abs()  # of operands taken for one region
        factor = 1 + parts.told * (self.sigma_told - 1)
        if boundary_read:  # the boundary specialist's own
            factor = torch.where((parts.told > 0) & (boundary >= 0), self.sigma_boundary, factor)
        sigma = self.sigma(union, parts.transferred, decrease, disagreement, split, factor)
        return union * parts.scale, sigma * parts.scale

    def proposal(
        self, a: Tensor, b: Tensor, exclude: Tensor | None = None, overlap: Tensor | None = None
    ) -> "Proposal":
        """What the memory and the correction say about a pair, before the blend (:meth:`blended`)."""
        scale = common_scale(a, b)
        za, zb = relative_log(a, scale), relative_log(b, scale)
        unions, distances, floors = self.memory(a, b, self.config.neighbours, exclude)
        priors = relative_log(unions, 1.0)  # (B, neighbours, k)
        floor = torch.minimum(za, zb)
        added = floors - priors  # what each neighbour's parts added to each other, in z
        transferred = floor[:, None] - added  # … taken off this pair's minimum
        read = [priors, transferred]
        disjoint = relative_log(disjoint_union(a, b), scale)
        if self.config.disjoint_prior:
            read.append(disjoint[:, None])
        told = torch.zeros_like(floor[:, :1])  # a hint this operator cannot read is not told
        if self.config.overlap_hint:
            hint, told = overlap_rows(overlap, floor)
            read.append(hint)
        change = self.correction(za, zb, torch.cat(read, dim=1), distances)
        gate = self.coincidence(za, zb)
        proposed = priors[:, 0] + change
        decrease = self.decreased(floor, proposed, gate) if self.config.parametrization == MONOTONE else None
        return Proposal(scale, za, zb, floor, added, transferred, distances, gate, proposed, decrease, told, disjoint)

    @staticmethod
    def told_decrease(
        parts: "Proposal", overlap: Tensor, specialist: ToldCorrection, boundary: Tensor | None = None
    ) -> Tensor:
        """(B, k) a told specialist's decrease (:class:`ToldCorrection`), gated like the
        correction's, so that one spectrum twice is its own union whatever it is told."""
        return parts.gate * specialist(parts.za, parts.zb, parts.disjoint, specialist.told(overlap, boundary))

    @property
    def reads_boundary(self) -> bool:
        """Whether the operator reads the boundary share (a boundary specialist is attached)."""
        return self.boundary_correction is not None

    def attach_told(self, specialist: ToldCorrection) -> None:
        """From now on ``specialist`` answers the pairs told their overlap, or, one that reads the
        boundary share, the pairs told that too (σ's told factor is then to be calibrated again:
        ``train_union.calibrate_told``)."""
        if specialist.told_columns > 1:
            self.boundary_correction = specialist
        else:
            self.told_correction = specialist

    @staticmethod
    def blend_terms(parts: "Proposal") -> tuple[Tensor, Tensor]:
        """The neighbours' median decrease, gated (B, k), and what the blend's weight reads (B, 5):
        1, the gate, how much the neighbours disagree on what they added (their standard
        deviation, mean over the spectrum), how far they are (mean key distance), and how much
        their median says was added (mean over the spectrum). Symmetric in the operands, like
        everything they are made of."""
        added = torch.clamp(parts.added, min=0)  # a union is never above its parts' minimum
        ordered = added.sort(dim=1).values
        count = added.shape[1]
        median = (ordered[:, (count - 1) // 2] + ordered[:, count // 2]) / 2
        features = torch.cat(
            [
                torch.ones_like(parts.gate),
                parts.gate,
                added.std(dim=1, correction=0).mean(-1, keepdim=True),
                parts.distances.mean(1, keepdim=True),
                median.mean(-1, keepdim=True),
            ],
            dim=1,
        )
        return parts.gate * median, features

    def blended(self, decrease: Tensor, median: Tensor, features: Tensor, told: Tensor) -> Tensor:
        """The network's decrease blended with the neighbours' median decrease (gated), outside
        training: w = sigmoid(features · ``blend_weights``) per pair, fitted on validation pairs
        after training (``train_union.fit_blend``).

        Why: the median of what the nearest training pairs' parts added (leave-one-body-out)
        beats the network where nothing or little is added — a re-scan, a view in another pose,
        a close-up inside a view — and loses to it where much is added; which of the two to
        trust is read off the neighbours themselves (their agreement, distance, and median) and
        the gate. Both decreases are non-negative and zero for one spectrum twice, so the blend
        keeps the bound, U(A, A) = A, commutativity and scale-equivariance. Unfitted (the
        default: a bias of −∞), w = 0 exactly: the network alone, as trained. Where the caller told
        the overlap (``told``), w = 0 too: the neighbours are found by their spectra alone, whatever
        their own overlap, and the network reads the hint they ignore.
        """
        weight = torch.sigmoid(features @ self.blend_weights)[:, None] * (1 - told)
        return (1 - weight) * decrease + weight * median

    def fitted(self) -> dict[str, float | list[float] | None]:
        """What was fitted beside the trained weights, for the metrics: the gate's width τ (None
        without a gate), the blend's weights (features of :meth:`blend_terms`, in order; None
        unfitted) and σ's four weights."""
        blend = [round(float(w), 4) for w in self.blend_weights]
        return {
            "gate_width": math.exp(self.log_gate_width.item()) if self.gated else None,
            "blend_weights": blend if all(map(math.isfinite, blend)) else None,
            "sigma_spread": float(self.sigma_scale),
            "sigma_floor": float(self.sigma_floor),
            "sigma_decrease": float(self.sigma_decrease),
            "sigma_disagreement": float(self.sigma_disagreement),
            "sigma_split": float(self.sigma_split),
            "sigma_told": float(self.sigma_told) if self.config.overlap_hint else None,
            "sigma_boundary": float(self.sigma_boundary) if self.reads_boundary else None,
        }

    @torch.no_grad()
    def set_blend_weights(self, weights: np.ndarray | tuple[float, ...]) -> None:
        self.blend_weights.copy_(torch.as_tensor(np.asarray(weights, dtype=np.float32)))

    def coincidence(self, za: Tensor, zb: Tensor) -> Tensor:
        """(B, 1): how far apart the operands are, 0 when their spectra are one, near 1 when
        they are as different as two parts' spectra usually are: 1 − exp(−msd / τ²), with msd
        the mean squared difference of their z and τ learned.

        A part united with itself adds nothing whatever the memory or the correction say, so
        the decrease is scaled by this gate: U(A, A) = A exactly, and a re-scan of the same region
        (spectra ~1–2 % apart) gets only a small share of the decrease the network proposes. It
        reads nothing but the two operands, so it holds on bodies and regions the memory never
        saw. Symmetric bit for bit ((a − b)² = (b − a)² in IEEE arithmetic) and scale-free (z is
        in the pair's common scale). The price: two different parts whose spectra coincide (a
        region and its mirror image) are united as one, which no spectrum-only operator can tell
        apart. Without the gate (``coincidence_gate=False``, or the PRIOR parametrization), 1.
        """
        if not self.gated:
            return torch.ones_like(za[:, :1])
        msd = (za - zb).pow(2).mean(-1, keepdim=True)
        return 1 - torch.exp(-msd * torch.exp(-2 * self.log_gate_width))

    @staticmethod
    def decreased(floor: Tensor, proposal: Tensor, gate: Tensor) -> Tensor:
        """The union's non-negative decrease in z from the operands' elementwise minimum.

        A Dirichlet eigenvalue only falls as the domain grows, so λ(A ∪ B) ≤ min(λ(A), λ(B)),
        with equality when nothing is added (A ∪ A, or A inside B). The decrease is a smooth
        positive part of how far the corrected prior lies below the minimum, times the
        coincidence ``gate`` (:meth:`coincidence`): "nothing added" is its natural zero, reached
        by a strongly negative signal or by operands that coincide, and the bound holds for every
        output by construction (sorting keeps it: the i-th smallest of values each below a sorted
        bound is below the bound's i-th). The union's z is ``floor`` minus it.
        """
        return gate * nn.functional.softplus(SHARPNESS * (floor - proposal)) / SHARPNESS

    @torch.no_grad()
    def set_sigma_told(self, factor: float) -> None:
        self.sigma_told.fill_(factor)

    def set_sigma_boundary(self, factor: float) -> None:
        self.sigma_boundary.fill_(factor)

    @torch.no_grad()
    def set_sigma_weights(
        self, spread: float, floor: float, decrease: float, disagreement: float, split: float = 0.0
    ) -> None:
        """The weights of σ's terms (:meth:`sigma`), as the calibration fits them."""
        self.sigma_scale.fill_(spread)
        self.sigma_floor.fill_(floor)
        self.sigma_decrease.fill_(decrease)
        self.sigma_disagreement.fill_(disagreement)
        self.sigma_split.fill_(split)

    def sigma(
        self,
        union: Tensor,
        transferred: Tensor,
        decrease: Tensor,
        disagreement: Tensor,
        split: Tensor,
        factor: Tensor | float = 1.0,
    ) -> Tensor:
        """σ relative to the common scale, from how far the neighbours' answers lie from the
        prediction, how far the prediction lies below the operands' minimum, how far apart
        two operands taken for one region are, and how far apart the network's and the
        neighbours' decreases are (the two answers :meth:`blended` mixes).

        A neighbour's answer here is what its parts added to each other, taken off this pair's
        minimum: neighbours that agree on that are sure, whatever their own size (a part with
        itself finds other parts with themselves, which added nothing, so σ shrinks to the
        floor; their unions themselves, other bodies' parts, spread widely). The root-mean-square
        distance in z of those answers is a spread of plausible answers; the decrease is how much
        the operator claims the parts add to each other, zero and certain for a part united with
        itself or with a part containing it. Two scans of one region (the gate near 0) differ by
        their pose and meshing, and the union is known no better than they agree: the third term
        is their difference in z at each eigenvalue, times 1 − gate (0 for parts the gate takes
        for different ones, and for one spectrum twice). The floor is what no pair escapes: a
        spectrum is one meshing's, and a scan's meshing is never the one its union's spectrum is
        taken on, so even one spectrum twice is its union only up to the meshing (a few per
        cent, growing with the index). Where the network and the neighbours disagree on how much
        the parts add (``split``, in z at each eigenvalue), one of them is wrong and the blend
        lies between them: their distance is how wrong the union may be (with it the 90 %
        interval's coverage of nested pairs in another meshing rose from 58 to 82 % on Test C,
        model card). The weights are fitted on validation data to a calibrated
        interval (``sigma_scale`` for the spread, ``sigma_floor`` — set a priori, see
        ``train_union.calibrate`` —, ``sigma_decrease`` for the decrease, ``sigma_disagreement``
        for the third, ``sigma_split`` for the last). A learned σ
        head, trained by Gaussian likelihood next to the mean, cost the mean a tenth of its
        accuracy (validation mae 5.1 → 5.5) and diverged on chains. ``factor`` (B, 1) scales every
        term but the floor: ``sigma_told`` for pairs told their overlap, who err less but whose
        union is known no better than its meshing.
        """
        spread = (transferred - relative_log(union, 1.0)[:, None]).pow(2).mean(1).sqrt()
        relative = spread * self.sigma_scale + decrease * self.sigma_decrease
        relative = relative + disagreement * self.sigma_disagreement + split * self.sigma_split
        return (relative * factor + self.sigma_floor) * (union + EPSILON)
