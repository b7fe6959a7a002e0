"""What every training run shares: device choice, seeding, schedule, resumable checkpoints.

A checkpoint is a plain dict (weights, optimizer, scheduler, config, epoch, best metric, best
weights) so that it loads without this package's classes and a killed run resumes exactly.
"""

import random
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import torch


def pick_device() -> torch.device:
    """The GPU when one is present, else the CPU: the same code trains on both."""
    return torch.device("cuda" if torch.cuda.is_available() else "cpu")


def seed_everything(seed: int) -> torch.Generator:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    return torch.Generator().manual_seed(seed)


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
) -> tuple[Progress, dict]:
    """Restore a run in place (batch order and noise included); returns its progress and best weights."""
    state = torch.load(path, map_location="cpu", weights_only=False)
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
