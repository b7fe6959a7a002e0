"""Train the region localizer on predicted unions (operator frozen) and noisy true spectra.

Samples: for each training row, the operator's leave-one-out predicted union with the union mask, and the
true spectra of part A, part B and the union (a full-coverage union is the whole body) with a
small multiplicative noise redrawn every epoch. The loss is the area-weighted cross-entropy
against the true mask or its mirror, whichever is smaller (spectra cannot tell them apart).
``identities`` restricts training to some identities, for the paper's single- and
six-identity tables. Early stopping on the validation rows' symmetric IoU.
"""

from dataclasses import asdict, dataclass, replace
from pathlib import Path

import numpy as np
import torch

from app.geometry import eigenpairs, mesh_operators
from training.common.data import PairTable, SpectralData
from training.common.fit import LoopSettings, Objective, fit, pick_device, seed_everything
from training.localizer.masks import symmetric_scores
from training.localizer.net import Localizer, LocalizerConfig, feature_statistics
from training.union.net import UnionOperator
from training.union.predict import memory_rows, predict


@dataclass(frozen=True)
class LocalizerTraining(LoopSettings):
    epochs: int = 40
    batch: int = 128
    weight_decay: float = 1e-6
    first_restart: int = 10
    patience: int = 10
    noise: float = 0.01  # relative noise on the true spectra, redrawn every epoch


def template_basis(data: SpectralData, count: int) -> tuple[np.ndarray, np.ndarray]:
    """(n, count) M-orthonormal eigenfunctions of the template, and its vertex areas."""
    operators = mesh_operators(data.template.vertices, data.template.faces)
    _, functions = eigenpairs(operators, count)
    return functions, operators.mass.diagonal()


def _samples(data: SpectralData, rows: PairTable, predicted: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(spectra, mask ids, noisy flag): predicted unions, then true parts and unions."""
    spectra = np.concatenate([predicted, rows.a, rows.b, rows.union])
    masks = np.concatenate([rows.mask_union, rows.mask_a, rows.mask_b, rows.mask_union])
    noisy = np.r_[np.zeros(len(predicted), bool), np.ones(3 * len(rows), bool)]
    return spectra.astype(np.float32), masks, noisy


def symmetric_loss(
    logits: torch.Tensor, truth: torch.Tensor, weights: torch.Tensor, mirror: torch.Tensor
) -> torch.Tensor:
    """Mean over the batch of min(BCE vs mask, BCE vs mirrored mask), area-weighted per vertex."""
    bce = torch.nn.functional.binary_cross_entropy_with_logits
    direct = (bce(logits, truth, reduction="none") * weights).sum(1)
    mirrored = (bce(logits, truth[:, mirror], reduction="none") * weights).sum(1)
    return torch.minimum(direct, mirrored).mean()


@torch.no_grad()
def localize(model: Localizer, spectra: np.ndarray, batch: int = 512) -> np.ndarray:
    """(m, n) boolean masks at probability ≥ 0.5."""
    return _read_logits(model, spectra, batch, lambda logits: logits >= 0)


def probabilities(model: Localizer, spectra: np.ndarray, batch: int = 512) -> np.ndarray:
    """(m, n) each template vertex's probability of lying in each spectrum's region."""
    return _read_logits(model, spectra, batch, torch.sigmoid)


def _read_logits(model: Localizer, spectra: np.ndarray, batch: int, read) -> np.ndarray:
    model.eval()
    device = next(model.parameters()).device
    out = []
    with torch.no_grad():
        for start in range(0, len(spectra), batch):
            chunk = torch.as_tensor(spectra[start : start + batch], dtype=torch.float32, device=device)
            out.append(read(model.logits(chunk)).cpu().numpy())
    return np.concatenate(out)


def train_localizer(
    data: SpectralData,
    union: UnionOperator,
    checkpoint: Path,
    identities: np.ndarray | None = None,
    settings: LocalizerTraining | None = None,
    config: LocalizerConfig | None = None,
) -> Localizer:
    """Train (or resume) a localizer and return its best weights, on the CPU."""
    settings, config = settings or LocalizerTraining(), config or LocalizerConfig()
    generator = seed_everything(settings.seed)
    device = pick_device()
    config = replace(config, k=data.spectra.shape[1])
    pairs = data.pairs
    train_rows = pairs.split == "train"
    if identities is not None:
        train_rows &= np.isin(data.identity_of(pairs.shape_a), identities)
    selected = np.flatnonzero(train_rows)
    train = pairs.rows(selected)
    validation = pairs.rows(np.flatnonzero(pairs.split == "validation"))
    # Leave-one-body-out unions: what the operator predicts for pairs of a body it has not stored.
    bodies = data.pairs.shape_a[memory_rows(data)]
    spectra, mask_ids, noisy = _samples(data, train, predict(union, train.a, train.b, (bodies, train.shape_a))[0])
    functions, areas = template_basis(data, config.basis or 1)
    mean, std = feature_statistics(spectra)
    model = Localizer(config, functions, mean, std).to(device)
    run_config = {
        "model": config.as_dict(),
        "training": asdict(settings),
        "identities": None if identities is None else [int(i) for i in identities],
    }
    weights = torch.as_tensor(areas / areas.sum(), dtype=torch.float32, device=device)
    mirror = torch.as_tensor(data.template.mirror, device=device)
    validation_spectra = predict(union, validation.a, validation.b, (bodies, validation.shape_a))[0]
    validation_masks = data.masks(validation.mask_union)

    def batch_loss(rows: torch.Tensor) -> torch.Tensor:
        picked = rows.cpu().numpy()
        x = torch.as_tensor(spectra[picked])
        jitter = 1 + settings.noise * torch.randn(x.shape, generator=generator)
        x = torch.where(torch.as_tensor(noisy[picked])[:, None], x * jitter, x).to(device)
        truth = torch.as_tensor(data.masks(mask_ids[picked]), dtype=torch.float32, device=device)
        return symmetric_loss(model.logits(x), truth, weights, mirror)

    def validation_loss() -> float:
        predicted = localize(model, validation_spectra)
        scores = symmetric_scores(predicted, validation_masks, areas, data.template.mirror, data.template.labels)
        return -float(scores.iou.mean())  # lower is better

    objective = Objective("localizer", len(spectra), batch_loss, validation_loss, lambda loss: f"{-loss:.4f}")
    fit(model, objective, settings, checkpoint, run_config, generator)
    return model.cpu().eval()
