"""Training the correspondence network on built parts (:mod:`training.correspondence.parts`).

One part per step (parts differ in size; a step on a 5 k-vertex part takes ~0.14 s on 2 cores),
Adam with a cosine schedule, from a fixed seed. The loss is the patch classification's cross
entropy, weighted by each vertex's area (a dense re-meshing must not count for more), plus the
distance from the place to the true rest-pose vertex (metres, area-weighted), which sharpens the
place within a patch. The checkpoint is a plain dict: weights, config, patches, step, losses.
"""

import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch

from app.contract import CORRESPONDENCE_INPUTS
from app.inference.template import Template
from training.correspondence.net import CorrespondenceConfig, CorrespondenceNet, stencil_matrices, template_patches

PLACE_WEIGHT = 10.0  # per metre: 1 cm of place error costs as much as 0.1 nats


@dataclass(frozen=True, kw_only=True)
class TrainingPreset:
    name: str
    steps: int  # the first cosine cycle
    learning_rate: float = 2e-3
    restarts: tuple[tuple[int, float], ...] = ()  # further cycles: (steps, starting learning rate)
    config: CorrespondenceConfig = CorrespondenceConfig()

    @property
    def cycles(self) -> list[tuple[int, float]]:
        return [(self.steps, self.learning_rate), *self.restarts]


TRAINING_PRESETS = {
    preset.name: preset
    for preset in (
        TrainingPreset(
            name="tiny", steps=20, restarts=((10, 1e-3),), config=CorrespondenceConfig(width=16, blocks=2, patches=64)
        ),
        TrainingPreset(name="standard", steps=24_000, restarts=((12_000, 5e-4),) * 3),
    )
}


def load_parts(directory: Path, split: str) -> list[dict[str, np.ndarray]]:
    """Every saved part of ``split`` ("train", "test_a", …), in index order."""
    paths = sorted((directory / "parts").glob(f"{split}-*.npz"))
    return [dict(np.load(path)) for path in paths]


def torch_inputs(part: dict[str, np.ndarray]) -> tuple[torch.Tensor, ...]:
    """A part's graph inputs as tensors, in the contract's order."""
    return tuple(torch.as_tensor(part[name]) for name in CORRESPONDENCE_INPUTS)


def train(parts_dir: Path, run: Path, preset: TrainingPreset, seed: int = 0, log=print) -> dict:
    """Train and return the checkpoint. ``run`` holding a checkpoint of the same preset is
    taken as it is when finished, and continued from the end of its last cycle otherwise: every
    cycle starts a fresh Adam from the weights the last left, and the parts drawn are the same
    sequence either way, so a continued run ends where one run from scratch would."""
    cycles = preset.cycles
    done = 0
    checkpoint = torch.load(run, weights_only=False) if run.exists() else None
    if checkpoint is not None and checkpoint["preset"] == preset.name:
        if checkpoint["step"] >= sum(steps for steps, _ in cycles):
            return checkpoint
        ends = list(np.cumsum([steps for steps, _ in cycles]))
        done = ends.index(checkpoint["step"]) + 1 if checkpoint["step"] in ends else 0
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    template = Template.load(parts_dir / "template")
    centres, patch = template_patches(template.vertices, template.faces, preset.config.patches)
    model = CorrespondenceNet(preset.config, centres)
    parts = load_parts(parts_dir, "train")
    if not parts:
        raise FileNotFoundError(f"no training parts under {parts_dir / 'parts'}")
    losses, seconds = [], 0.0
    if done:
        model.load_state_dict(checkpoint["model"])
        losses, seconds = list(map(tuple, checkpoint["losses"])), checkpoint["seconds"]
        for _ in losses:  # the parts the finished cycles drew, one draw at a time as they were drawn
            rng.integers(len(parts))
    inputs_of = [torch_inputs(part) for part in parts]
    stencils = [stencil_matrices(inputs[4], inputs[5]) for inputs in inputs_of]
    data = _TrainingData(parts, inputs_of, stencils, torch.as_tensor(template.vertices, dtype=torch.float32), patch)
    run.parent.mkdir(parents=True, exist_ok=True)
    for steps, learning_rate in cycles[done:]:
        started = time.perf_counter()
        losses += _cycle(model, data, steps, learning_rate, rng, log)
        seconds += time.perf_counter() - started
        # Saved at every cycle's end, so that a run stopped in a later cycle continues from here.
        checkpoint = {
            "model": model.state_dict(),
            "config": preset.config.as_dict(),
            "centres": centres,
            "patch": patch,
            "preset": preset.name,
            "training": asdict(preset) | {"config": preset.config.as_dict()},
            "seed": seed,
            "step": len(losses),
            "losses": np.asarray(losses),
            "seconds": seconds,
        }
        torch.save(checkpoint, run)
    return checkpoint


@dataclass(frozen=True)
class _TrainingData:
    parts: list[dict[str, np.ndarray]]
    inputs: list[tuple[torch.Tensor, ...]]
    stencils: list
    rest: torch.Tensor  # (V, 3) the template's rest pose
    patch: np.ndarray  # (V,) each template vertex's patch


def _cycle(
    model: CorrespondenceNet, data: _TrainingData, steps: int, learning_rate: float, rng: np.random.Generator, log
) -> list[tuple[float, float]]:
    """One cosine cycle of ``steps`` steps from ``learning_rate``, a fresh Adam; each step's
    (cross entropy, place error in metres)."""
    optimizer = torch.optim.Adam(model.parameters(), lr=learning_rate)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, steps)
    patch_of = torch.as_tensor(data.patch)
    losses, started, every = [], time.perf_counter(), max(steps // 20, 1)
    for step in range(steps):
        chosen = int(rng.integers(len(data.parts)))
        part = data.parts[chosen]
        target = torch.as_tensor(part["target"])
        area = torch.as_tensor(part["mass"])
        area = area / area.sum()
        heads = model.heads(*data.inputs[chosen], data.stencils[chosen])
        position, _ = model.place(heads)
        classification = (
            torch.nn.functional.cross_entropy(heads.logits, patch_of[target], reduction="none") * area
        ).sum()
        place = (torch.linalg.norm(position - data.rest[target], dim=1) * area).sum()
        loss = classification + PLACE_WEIGHT * place
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        schedule.step()
        losses.append((float(classification.detach()), float(place.detach())))
        if (step + 1) % every == 0:
            recent = np.mean(losses[-every:], axis=0)
            log(
                f"step {step + 1}/{steps} (from {learning_rate:g}): cross entropy {recent[0]:.3f}, "
                f"place {100 * recent[1]:.1f} cm, {time.perf_counter() - started:.0f} s"
            )
    return losses


def restored(checkpoint: dict) -> CorrespondenceNet:
    """The trained network of a checkpoint, in evaluation mode."""
    model = CorrespondenceNet(CorrespondenceConfig(**checkpoint["config"]), checkpoint["centres"])
    model.load_state_dict(checkpoint["model"])
    return model.eval()
