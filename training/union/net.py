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

Everything is in the pair's common scale and relative-log space (:mod:`union_memory`), which
makes the operator exactly scale-equivariant, as the true union is. The output is sorted, so it
is non-decreasing by construction.
"""

import math
from typing import NamedTuple

import numpy as np
import torch
from torch import Tensor, nn

from app.contract import UNKNOWN_OVERLAP
from training.union.config import MONOTONE, UnionConfig
from training.union.corrections import CORRECTIONS, ToldCorrection
from training.union.memory import EPSILON, UnionMemory, common_scale, disjoint_union, relative_log

SIGMA_FLOOR = 1e-2  # the smallest relative σ before calibration (the pose noise floor is ~2 %)
SHARPNESS = 20.0  # of the softplus that turns the monotone parametrization's signal into a decrease
# The coincidence gate's starting width τ in z (RMS over the spectrum): a re-scan of one region
# differs by ~1–2 % (the pose noise floor), two different parts by tens of per cent. Learned.
GATE_WIDTH = 0.03
UNFITTED_BLEND = (-math.inf, 0.0, 0.0, 0.0, 0.0)  # UnionOperator.blended's weights before fitting: w = 0


def overlap_rows(overlap: Tensor | None, like: Tensor) -> tuple[Tensor, Tensor]:
    """The hint as the correction reads it, (B, 2, k): its value (0 when unknown) and 1 where it
    is known, at every eigenvalue index; and ``told`` (B, 1), 1 where it is known."""
    if overlap is None:
        overlap = torch.full_like(like[:, :1], UNKNOWN_OVERLAP)
    told = (overlap >= 0).to(like.dtype)
    value = torch.clamp(overlap, min=0.0, max=1.0) * told
    return torch.stack([value.expand_as(like), told.expand_as(like)], dim=1), told


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
        assert config.correction in CORRECTIONS, config.correction
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
        ``union_sigma.calibrate_told``)."""
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
        after training (``union_blend.fit_blend``).

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
        ``union_sigma.calibrate`` —, ``sigma_decrease`` for the decrease, ``sigma_disagreement``
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
