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
from app.inference import Template
from training.common.fit import OtherRecipe
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


def recipe(preset: TrainingPreset, seed: int) -> dict:
    """What decides a run's weights: the preset (its cycles and network) and the seed."""
    return asdict(preset) | {"config": preset.config.as_dict(), "seed": seed}


def cycles_done(checkpoint: dict, preset: TrainingPreset, seed: int) -> int | None:
    """How many of ``preset``'s cycles ``checkpoint`` holds finished, None where it was trained
    by another recipe. A checkpoint continues a run only where it was trained by the same recipe,
    or by one whose cycles are the first of this one's (more cycles added): a name alone says
    nothing once a width or a feature changed, and a stale checkpoint taken as finished would be
    exported as if it were this recipe's."""
    asked, held = recipe(preset, seed), checkpoint.get("training", {}) | {"seed": checkpoint.get("seed")}
    held_cycles = [(held.get("steps"), held.get("learning_rate")), *map(tuple, held.get("restarts", ()))]
    same = {key: value for key, value in asked.items() if key not in ("steps", "learning_rate", "restarts")}
    if any(held.get(key) != value for key, value in same.items()) or held_cycles != preset.cycles[: len(held_cycles)]:
        return None
    ends = list(np.cumsum([steps for steps, _ in preset.cycles]))
    return ends.index(checkpoint["step"]) + 1 if checkpoint["step"] in ends else 0


def train(parts_dir: Path, run: Path, preset: TrainingPreset, seed: int = 0, log=print) -> dict:
    """Train and return the checkpoint. ``run`` holding a checkpoint of the same recipe
    (:func:`cycles_done`) is taken as it is when finished, and continued from the end of its last
    cycle otherwise: every cycle starts a fresh Adam from the weights the last left, and the
    parts drawn are the same sequence either way, so a continued run ends where one run from
    scratch would. A checkpoint of another recipe is refused (:class:`OtherRecipe`), not
    overwritten."""
    cycles = preset.cycles
    checkpoint = torch.load(run, weights_only=False) if run.exists() else None
    done = cycles_done(checkpoint, preset, seed) if checkpoint is not None else 0
    if done is None:
        raise OtherRecipe(
            f"{run} holds a checkpoint trained by another recipe than preset {preset.name!r} with seed {seed} "
            "(another network, cycles or seed): move it away or train into another runs folder"
        )
    if done == len(cycles):
        return checkpoint
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
            "training": recipe(preset, seed),
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
