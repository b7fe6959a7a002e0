"""What every training run shares: device choice, seeding, the loop with its schedule, early
stopping and resumable checkpoints.

Each trainer (:mod:`training.union.train`, :mod:`training.localizer.train`)
says only what is its own: how a batch of rows becomes a loss, and how an epoch is validated.
A checkpoint is a plain dict (weights, optimizer, scheduler, config, epoch, best metric, best
weights) so that it loads without this package's classes and a killed run resumes exactly. It
is continued only by the run configuration it was trained with: a checkpoint of another width,
feature set or schedule left in the runs folder is refused (:class:`OtherRecipe`), never taken
up as if it were this run's.
"""

import random
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch
from tqdm import tqdm


def pick_device() -> torch.device:
    """The GPU when one is present, else the CPU: the same code trains on both."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def seed_everything(seed: int) -> torch.Generator:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    return torch.Generator().manual_seed(seed)


@dataclass(frozen=True)
class LoopSettings:
    """What the loop itself needs; each trainer's settings extend it with their own."""

    epochs: int = 60
    batch: int = 64
    learning_rate: float = 1e-3
    weight_decay: float = 1e-5
    first_restart: int = 60  # epochs of the first cosine cycle (each next one twice as long)
    patience: int = 25  # epochs without a better validation metric before stopping
    clip_norm: float | None = None  # the gradient's largest norm; None: not clipped
    seed: int = 0


def optimizer_and_schedule(
    model: torch.nn.Module, learning_rate: float, weight_decay: float, first_restart: int
) -> tuple[torch.optim.Optimizer, torch.optim.lr_scheduler.LRScheduler]:
    """Adam with cosine annealing and warm restarts (period doubling), stepped per epoch."""
    optimizer = torch.optim.Adam(model.parameters(), lr=learning_rate, weight_decay=weight_decay)
    schedule = torch.optim.lr_scheduler.CosineAnnealingWarmRestarts(optimizer, T_0=first_restart, T_mult=2)
    return optimizer, schedule


@dataclass
class Progress:
    """Where a run stands; saved in every checkpoint."""

    epoch: int = 0
    best_metric: float = float("inf")  # lower is better
    best_epoch: int = -1
    stale_epochs: int = 0
    history: list[float] = field(default_factory=list)  # the validation metric of every epoch

    def remaining(self, epochs: int, patience: int) -> range:
        """The epochs still to train: none once the budget is spent or validation went stale
        (so resuming a finished run, early-stopped or not, trains nothing)."""
        stopped = bool(self.history) and self.stale_epochs >= patience
        return range(self.epoch, self.epoch if stopped else epochs)

    def finish_epoch(self, epoch: int, metric: float) -> bool:
        """Record a finished epoch's validation metric; True when it is the best so far."""
        self.epoch = epoch + 1
        self.history.append(metric)
        if metric < self.best_metric:
            self.best_metric, self.best_epoch, self.stale_epochs = metric, epoch, 0
            return True
        self.stale_epochs += 1
        return False


# How long a run goes on is not its recipe: the same run, trained further or stopped later, is
# the run an uninterrupted one of that length would be (the schedule does not read them).
CONTINUABLE = ("training.epochs", "training.patience")


class OtherRecipe(ValueError):
    """A run's checkpoint was trained by another recipe than the one asked for."""


def require_recipe(path: Path, held: dict | None, config: dict) -> None:
    """Refuse to continue the checkpoint at ``path`` (trained with ``held``) as a run of
    ``config``, naming what differs."""
    held, config = _flat(held or {}), _flat(config)
    differs = sorted(
        key for key in held.keys() | config.keys() if key not in CONTINUABLE and held.get(key) != config.get(key)
    )
    if not differs:
        return
    shown = ", ".join(f"{key}: {held.get(key)!r} there, {config.get(key)!r} here" for key in differs[:4])
    raise OtherRecipe(f"{path} was trained by another recipe ({shown}): move it away or train into another runs folder")


def _flat(config: dict, prefix: str = "") -> dict:
    """A nested configuration as dotted keys, so that a difference is named where it lies."""
    out = {}
    for key, value in config.items():
        if isinstance(value, dict):
            out |= _flat(value, f"{prefix}{key}.")
        else:
            out[f"{prefix}{key}"] = value
    return out


def snapshot(model: torch.nn.Module) -> dict:
    """A detached copy of the weights (the best epoch's, kept while training goes on)."""
    return {k: v.detach().clone() for k, v in model.state_dict().items()}


def save_checkpoint(
    path: Path,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    schedule: torch.optim.lr_scheduler.LRScheduler,
    config: dict,
    progress: Progress,
    best_weights: dict,
    generator: torch.Generator,
) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    state = {
        "weights": model.state_dict(),
        "optimizer": optimizer.state_dict(),
        "schedule": schedule.state_dict(),
        "config": config,
        "epoch": progress.epoch,
        "best_metric": progress.best_metric,
        "best_epoch": progress.best_epoch,
        "stale_epochs": progress.stale_epochs,
        "history": progress.history,
        "best_weights": best_weights,
        "torch_rng": torch.get_rng_state(),
        "generator": generator.get_state(),
    }
    temporary = path.with_suffix(".tmp")
    torch.save(state, temporary)
    temporary.replace(path)  # a kill mid-write never leaves a truncated checkpoint


def validation_history(path: Path) -> list[float]:
    """The validation metric of every epoch of the run checkpointed at ``path``."""
    return list(torch.load(path, map_location="cpu", weights_only=False)["history"])


def load_checkpoint(
    path: Path,
    model: torch.nn.Module,
    optimizer: torch.optim.Optimizer,
    schedule: torch.optim.lr_scheduler.LRScheduler,
    generator: torch.Generator,
    config: dict,
) -> tuple[Progress, dict]:
    """Restore a run of ``config`` in place (batch order and noise included); returns its progress
    and best weights. Raises :class:`OtherRecipe` for a checkpoint of another configuration."""
    state = torch.load(path, map_location="cpu", weights_only=False)
    require_recipe(path, state.get("config"), config)
    model.load_state_dict(state["weights"])
    optimizer.load_state_dict(state["optimizer"])
    schedule.load_state_dict(state["schedule"])
    torch.set_rng_state(state["torch_rng"])
    generator.set_state(state["generator"])
    return _progress(state), state["best_weights"]


def _progress(state: dict) -> Progress:
    return Progress(
        state["epoch"], state["best_metric"], state["best_epoch"], state["stale_epochs"], list(state["history"])
    )


def is_finished(path: Path, epochs: int, patience: int) -> bool:
    """Whether the run checkpointed at ``path`` exists and has nothing left to train."""
    if not path.exists():
        return False
    return not _progress(torch.load(path, map_location="cpu", weights_only=False)).remaining(epochs, patience)


@dataclass(frozen=True)
class Objective:
    """A trainer's own part of the loop.

    ``batch_loss`` turns a batch of sample indices (a tensor, drawn by the loop from the run's
    generator) into the loss; ``validate`` scores the model after an epoch, lower is better;
    ``shown`` is how the progress bar prints that score (e.g. an IoU for its negative).
    """

    label: str
    samples: int
    batch_loss: Callable[[torch.Tensor], torch.Tensor]
    validate: Callable[[], float]
    shown: Callable[[float], str]


def fit(
    model: torch.nn.Module,
    objective: Objective,
    settings: LoopSettings,
    checkpoint: Path,
    run_config: dict,
    generator: torch.Generator,
) -> torch.nn.Module:
    """Train ``model`` in place (or resume its checkpoint) and load its best epoch's weights.

    Every epoch: one pass over a fresh permutation of the samples in batches (the last partial
    batch dropped), Adam with the warm-restart cosine schedule stepped per batch, the gradient
    clipped when ``settings.clip_norm`` says so, then validation, a checkpoint, and a stop once
    validation has not improved for ``settings.patience`` epochs.
    """
    optimizer, schedule = optimizer_and_schedule(
        model, settings.learning_rate, settings.weight_decay, settings.first_restart
    )
    progress, best = Progress(), snapshot(model)
    if checkpoint.exists():
        progress, best = load_checkpoint(checkpoint, model, optimizer, schedule, generator, run_config)
    device = next(model.parameters()).device
    steps = max(1, objective.samples // settings.batch)
    epochs = progress.remaining(settings.epochs, settings.patience)
    bar = tqdm(epochs, desc=objective.label, unit="epoch", initial=progress.epoch, total=settings.epochs)
    for epoch in bar:
        model.train()
        order = torch.randperm(objective.samples, generator=generator)
        for step in range(steps):
            loss = objective.batch_loss(order[step * settings.batch : (step + 1) * settings.batch].to(device))
            optimizer.zero_grad(set_to_none=True)
            loss.backward()
            if settings.clip_norm is not None:
                torch.nn.utils.clip_grad_norm_(model.parameters(), settings.clip_norm)
            optimizer.step()
            schedule.step(epoch + (step + 1) / steps)
        metric = objective.validate()
        if progress.finish_epoch(epoch, metric):
            best = snapshot(model)
        bar.set_postfix(val=objective.shown(metric), best=objective.shown(progress.best_metric))
        save_checkpoint(checkpoint, model, optimizer, schedule, run_config, progress, best, generator)
        if progress.stale_epochs >= settings.patience:
            break
    model.load_state_dict(best)
    return model
