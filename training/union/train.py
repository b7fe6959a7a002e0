"""Train the union operator's correction on pairs and on chains (A ∪ B) ∪ C of the data set.

The operator's memory holds the training pairs (validation excluded); every training pair is
predicted leave-one-body-out, every memory row cut from the same posed body hidden, so the
correction learns what a prior from *another* body gets wrong. Hiding the own row alone is not
enough since pairs overlap as scans do: a pair's identical, re-scanned and nested siblings and
the other views of its scanning session are all cut from its body, and their unions are its
union or nearly, which no pair of a new body has in the memory. Every step also sees a smaller
batch of chains whose inner union is the operator's *own prediction*, so errors are trained not
to grow along a chain. Inputs get a small multiplicative jitter (the spectrum of a fixed region
moves ~1 % across poses). The best epoch by a validation metric (``selection``) is kept; then,
on the validation rows, the blend of the network's decrease with the neighbours' is fitted
(:mod:`union_blend`) and σ calibrated (:mod:`union_sigma`).
"""

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch
from scipy import sparse

from app.contract import UNKNOWN_OVERLAP
from training.common.data import PairTable, SpectralData
from training.common.fit import LoopSettings, Objective, fit, pick_device, seed_everything
from training.common.spectral_errors import spectral_errors
from training.data.pairs import FULL_COVERAGE
from training.data.spectra import REMESHED
from training.data.splits import TEST_B_MAX_IOU
from training.union.blend import fit_blend_on
from training.union.config import UnionConfig
from training.union.corrections import ToldCorrection
from training.union.memory import common_scale, disjoint_union, relative_log
from training.union.net import SIGMA_FLOOR, UnionOperator
from training.union.predict import build_operator, memory_rows, predict, same_body, tensor
from training.union.sigma import calibrate, calibrate_told


@dataclass(frozen=True)
class UnionTraining(LoopSettings):
    chain_batch: int = 16  # chains (A ∪ B) ∪ C next to each batch of pairs
    clip_norm: float | None = 1.0  # the transformers' early steps spike without it
    jitter: float = 0.01  # relative input noise: a region's spectrum across poses
    dropout: float = 0.0
    loss: str = "absolute"  # a key of CASE_LOSSES
    # σ's floor, relative to the spread's weight, as the calibration may choose it: the served
    # models keep the fixed 0.01; a grid lets validation re-meshed rows (if any) set it.
    sigma_floors: tuple[float, ...] = (SIGMA_FLOOR,)
    selection: str = "mae"  # the validation metric that picks the epoch kept: a key of spectral_errors
    # The share of training rows whose memory also hides the pairs whose union is of their union's
    # type (:func:`union_kin`): pairs as Test B's are, whose union no training pair shares.
    hide_union_type: float = 0.0
    # Draw the training rows whose union falls short of the body evenly over SIZE_BINS bins of the
    # union's share of the body (the whole-body rows keep their share of the batches): see size_weights.
    balance_union_sizes: bool = False
    # An operator that reads the overlap (UnionConfig.overlap_hint) is told it for this share of
    # the training rows, unknown for the rest (so it serves callers who cannot tell it as well),
    # with this much absolute noise: a caller measures it, never exactly.
    overlap_told: float = 0.5
    overlap_noise: float = 0.05
    # The told specialist (UnionConfig.told_width > 0, train_told): epochs over the training rows,
    # batch, and the peak of its one-cycle learning rate.
    told_epochs: int = 40
    told_batch: int = 256
    told_learning_rate: float = 2e-3
    # The boundary specialist (UnionConfig.told_boundary) is told each row's boundary share with
    # this much absolute noise: measured from registered views it is off by 0.03 on average, 0.06
    # at the 95th percentile (the Test C sessions, benchmarks.measured_overlap).
    boundary_noise: float = 0.04


def _jitter(x: torch.Tensor, amount: float, generator: torch.Generator) -> torch.Tensor:
    noise = torch.randn(x.shape, generator=generator).to(x.device)
    return x * (1 + amount * noise)


# union_kin: template vertices sampled (fixed seed) to compare union regions by; queries per product.
KIN_VERTICES = 2048
KIN_CHUNK = 1024


def union_kin(data: SpectralData, queries: np.ndarray, memory: np.ndarray) -> sparse.csr_matrix:
    """(len(queries), len(memory)) boolean: which ``memory`` rows have a union of the same type
    as each query row's, i.e. a symmetric area IoU (as it is or mirrored) of at least
    ``TEST_B_MAX_IOU`` on a fixed sample of template vertices (a row is its own kin).
    Full-coverage pairs (their union is the whole body, a type every body has) have no kin.

    Why: leave-one-body-out training still shows every pair the unions of its own type cut from
    other bodies, so the network learns to trust its nearest neighbours; Test B's unions are,
    by construction, unlike every training union (IoU below the same threshold), and there it
    was worse than the plain disjoint union. Hiding a row's kin from its memory in training is
    Test B's situation, made from training rows alone.
    """
    pairs = data.pairs
    partial = [np.flatnonzero(pairs.scenario[rows] != FULL_COVERAGE) for rows in (queries, memory)]
    masks = [pairs.mask_union[rows[kept]] for rows, kept in zip((queries, memory), partial, strict=True)]
    unique, inverse = np.unique(np.concatenate(masks), return_inverse=True)
    template = data.template
    count = len(template.vertices)
    sample = np.sort(np.random.default_rng([0, 11]).choice(count, min(count, KIN_VERTICES), replace=False))
    full = data.masks(unique)
    regions, mirrored = full[:, sample].astype(np.float32), full[:, template.mirror[sample]].astype(np.float32)
    weights = data.vertex_area[sample].astype(np.float32)
    areas = regions @ weights
    linked = []
    for start in range(0, len(unique), KIN_CHUNK):
        query, query_areas = regions[start : start + KIN_CHUNK] * weights, areas[start : start + KIN_CHUNK, None]
        best = np.zeros((len(query), len(unique)), dtype=np.float32)
        for other in (regions, mirrored):
            shared = query @ other.T
            best = np.maximum(best, shared / np.maximum(query_areas + areas - shared, 1e-12))
        linked.append(sparse.csr_matrix(best >= TEST_B_MAX_IOU))
    kin_types = sparse.vstack(linked).tocsr()
    members = [
        sparse.csr_matrix((np.ones(len(kept), dtype=bool), (kept, types)), shape=(len(rows), len(unique)))
        for rows, kept, types in zip((queries, memory), partial, np.split(inverse, [len(partial[0])]), strict=True)
    ]
    return (members[0] @ kin_types @ members[1].T).astype(bool).tocsr()


SIZE_BINS = 10  # bins of the union's share of the body over which size_weights draws evenly


def size_weights(data: SpectralData, rows: np.ndarray) -> np.ndarray:
    """(len(rows),) sampling weights summing to 1: the whole-body rows keep their share, the
    others share the rest evenly among ``SIZE_BINS`` bins of their union's share of the body
    (uniform in each bin).

    Why: the random draws make most partial unions large (median 84 % of the body) and leave
    mid-sized ones split along a thin band, where two parts add nearly all of each other, to
    ~4 % of the rows (docs/decisions/010); scans come in every size.
    """
    pairs = data.pairs
    share = data.coverage(pairs.mask_union[rows])
    whole = pairs.scenario[rows] == FULL_COVERAGE
    bins = np.minimum((share * SIZE_BINS).astype(int), SIZE_BINS - 1)
    counts = np.bincount(bins[~whole], minlength=SIZE_BINS)
    weights = np.full(len(rows), 1.0 / len(rows))  # a whole-body row: its share as drawn uniformly
    weights[~whole] = (~whole).mean() / np.count_nonzero(counts) / counts[bins[~whole]]
    return weights / weights.sum()


# The error of the relative logs z = log(λ / s + ε) per eigenvalue, made a loss. Either is close
# to the relative error of every eigenvalue, the figure we report; the paper's MSE in 1/m² is
# ruled by the top eigenvalues (λ₂₀ of a part is ~100× its λ₁) and left the transformer at 33 %
# relative error on validation. The absolute error is the mean relative error itself; its
# minimizer is the median of the plausible unions, not their mean, which matters where two
# part spectra leave the union ambiguous between "nothing added" (one part inside the other)
# and "something added": the mean lands between the two, wrong for both.
CASE_LOSSES = {"absolute": torch.abs, "squared": torch.square}


def _losses(
    model: UnionOperator,
    pairs: tuple[torch.Tensor, ...],
    hidden: torch.Tensor,
    chains: tuple[torch.Tensor, ...] | None,
    loss: str,
    overlap: torch.Tensor | None = None,
) -> torch.Tensor:
    def case(mean: torch.Tensor, truth: torch.Tensor, scale: torch.Tensor) -> torch.Tensor:
        return CASE_LOSSES[loss](relative_log(mean, scale) - relative_log(truth, scale)).mean()

    a, b, union = pairs
    total = case(model(a, b, hidden, overlap)[0], union, common_scale(a, b))
    if chains is not None:
        a, b, c, ab, abc = chains
        inner = model(a, b)[0]
        total = total + case(inner, ab, common_scale(a, b))
        total = total + case(model(inner, c)[0], abc, common_scale(inner, c))
    return total


def train_union(
    data: SpectralData,
    checkpoint: Path,
    settings: UnionTraining | None = None,
    config: UnionConfig | None = None,
) -> UnionOperator:
    """Train (or resume) and return the best model, calibrated, on the CPU."""
    settings, config = settings or UnionTraining(), config or UnionConfig()
    generator = seed_everything(settings.seed)
    device = pick_device()
    config = replace(config, k=data.spectra.shape[1], dropout=settings.dropout)
    pairs = data.pairs
    memory = memory_rows(data)
    train = pairs.rows(memory)
    validation = pairs.rows(np.flatnonzero(pairs.split == "validation"))
    model = build_operator(train, config).to(device)
    run_config = {"model": config.as_dict(), "training": asdict(settings)}
    train_tensors = [tensor(x, device) for x in (train.a, train.b, train.union)]
    memory_bodies = torch.as_tensor(train.shape_a, device=device)
    bodies = (train.shape_a, validation.shape_a)
    chain_rows = np.flatnonzero(~data.triples.test)
    chain_tensors = [tensor(s[chain_rows], device) for s in data.triples.spectra]
    kin = union_kin(data, memory, memory) if settings.hide_union_type > 0 else None
    drawn = torch.as_tensor(size_weights(data, memory)) if settings.balance_union_sizes else None
    shares = tensor(data.overlap_shares(train.mask_a, train.mask_b), device) if config.overlap_hint else None

    def batch_loss(rows: torch.Tensor) -> torch.Tensor:
        if drawn is not None:  # the loop's rows replaced by as many drawn by union size
            rows = torch.multinomial(drawn, len(rows), replacement=True, generator=generator).to(device)
        a, b = (_jitter(t[rows], settings.jitter, generator) for t in train_tensors[:2])
        batch = (a, b, train_tensors[2][rows])
        chains = None
        if len(chain_rows):
            pick = torch.randint(len(chain_rows), (settings.chain_batch,), generator=generator).to(device)
            chains = tuple(t[pick] for t in chain_tensors)
        hidden = same_body(memory_bodies, memory_bodies[rows])
        if kin is not None:
            chosen = torch.rand(len(rows), generator=generator) < settings.hide_union_type
            of_kind = torch.as_tensor(kin[rows.cpu().numpy()].toarray(), device=device)
            hidden = hidden | (of_kind & chosen.to(device)[:, None])
        overlap = None if shares is None else _told(shares[rows], settings, generator)
        return _losses(model, batch, hidden, chains, settings.loss, overlap)

    def validation_metric() -> float:
        predicted = predict(model, validation.a, validation.b, bodies)[0]
        return spectral_errors(predicted, validation.union)[settings.selection]

    objective = Objective("union", len(train), batch_loss, validation_metric, lambda metric: f"{metric:.4g}")
    fit(model, objective, settings, checkpoint, run_config, generator)
    fit_blend_on(model, data)
    remeshed = validation.variant == REMESHED
    calibrate(model, validation.a, validation.b, validation.union, remeshed, bodies, settings.sigma_floors)
    if config.overlap_hint and config.told_width > 0:
        shares = data.overlap_shares(train.mask_a, train.mask_b)
        model.attach_told(train_told(model, train, shares, settings))
        if config.told_boundary:
            boundaries = data.boundary_shares(train.mask_a, train.mask_b, train.mask_union)
            model.attach_told(train_told(model, train, shares, settings, boundaries))
    if config.overlap_hint:
        told = data.overlap_shares(validation.mask_a, validation.mask_b)
        calibrate_told(model, validation.a, validation.b, validation.union, told, bodies)
        if model.reads_boundary:
            edges = data.boundary_shares(validation.mask_a, validation.mask_b, validation.mask_union)
            calibrate_told(model, validation.a, validation.b, validation.union, told, bodies, edges)
    model.cpu().eval()
    return model


def train_told(
    model: UnionOperator,
    train: PairTable,
    shares: np.ndarray,
    settings: UnionTraining,
    boundaries: np.ndarray | None = None,
) -> ToldCorrection:
    """The told specialist (:class:`ToldCorrection`) trained on the training pairs, each told its
    true ``shares`` plus ``settings.overlap_noise`` of noise, to the same loss as the correction,
    with everything else of ``model`` (its coincidence gate) as trained; with ``boundaries``, a
    specialist that reads the boundary share too, told it plus ``settings.boundary_noise``.
    Seeded from ``settings.seed`` and deterministic on the CPU; ~1 min on 2 cores for the
    standard set.

    It reads no memory, so every input is computed once: only the network's own weights move.
    """
    generator = torch.Generator().manual_seed(settings.seed)
    torch.manual_seed(settings.seed)
    a, b, union = (tensor(x, torch.device("cpu")) for x in (train.a, train.b, train.union))
    with torch.no_grad():
        scale = common_scale(a, b)
        za, zb = relative_log(a, scale), relative_log(b, scale)
        disjoint = relative_log(disjoint_union(a, b), scale)
        gate = model.cpu().coincidence(za, zb)
        floor, target = torch.minimum(za, zb), relative_log(union, scale)
    share = tensor(shares, torch.device("cpu"))[:, None]
    edge = None if boundaries is None else tensor(boundaries, torch.device("cpu"))[:, None]
    specialist = ToldCorrection(za.shape[1], model.config.told_width, boundary=edge is not None)
    specialist.set_standardization(ToldCorrection.inputs(za, zb, disjoint, specialist.told(share, edge)))
    optimizer = torch.optim.Adam(specialist.parameters(), lr=settings.told_learning_rate)
    steps_per_epoch = -(-len(a) // settings.told_batch)
    schedule = torch.optim.lr_scheduler.OneCycleLR(
        optimizer, settings.told_learning_rate, total_steps=settings.told_epochs * steps_per_epoch
    )
    specialist.train()
    for _ in range(settings.told_epochs):
        order = torch.randperm(len(a), generator=generator)
        for start in range(0, len(a), settings.told_batch):
            rows = order[start : start + settings.told_batch]
            noise = torch.randn(len(rows), 1, generator=generator) * settings.overlap_noise
            told = specialist.told(
                torch.clamp(share[rows] + noise, 0.0, 1.0), _boundary_told(edge, rows, settings, generator)
            )
            z = floor[rows] - gate[rows] * specialist(za[rows], zb[rows], disjoint[rows], told)
            loss = CASE_LOSSES[settings.loss](z - target[rows]).mean()
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
            schedule.step()
    return specialist.eval()


def _boundary_told(
    boundaries: torch.Tensor | None, rows: torch.Tensor, settings: UnionTraining, generator: torch.Generator
) -> torch.Tensor | None:
    """(B, 1) what a batch of the boundary specialist's rows is told of their boundary shares: the
    true one plus noise, clipped to 0 … 1. None for a specialist that does not read it (drawing
    nothing: the share-only specialist trains as it did before there was another)."""
    if boundaries is None:
        return None
    noise = torch.randn(len(rows), 1, generator=generator) * settings.boundary_noise
    return torch.clamp(boundaries[rows] + noise, 0.0, 1.0)


def _told(shares: torch.Tensor, settings: UnionTraining, generator: torch.Generator) -> torch.Tensor:
    """(B, 1) what a batch is told of its overlaps: the true share plus noise, clipped to 0 … 1,
    for ``settings.overlap_told`` of the rows; UNKNOWN_OVERLAP for the others."""
    noise = torch.randn(shares.shape, generator=generator).to(shares.device) * settings.overlap_noise
    told = torch.rand(shares.shape, generator=generator).to(shares.device) < settings.overlap_told
    measured = torch.clamp(shares + noise, 0.0, 1.0)
    return torch.where(told, measured, torch.full_like(shares, UNKNOWN_OVERLAP))[:, None]


def load_operator(data: SpectralData, checkpoint: Path) -> UnionOperator:
    """A finished run's operator at its kept epoch, its blend fitted, on the CPU, for its means
    (σ uncalibrated): e.g. to predict pairs leave-one-body-out (:func:`predict` with ``bodies``)
    for another model."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    model = build_operator(data.pairs.rows(memory_rows(data)), UnionConfig(**state["config"]["model"]))
    model.load_state_dict(state["best_weights"])
    fit_blend_on(model, data)
    return model.eval()
