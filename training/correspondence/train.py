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
    steps: int
    learning_rate: float = 2e-3
    config: CorrespondenceConfig = CorrespondenceConfig()


TRAINING_PRESETS = {
    preset.name: preset
    for preset in (
        TrainingPreset(name="tiny", steps=30, config=CorrespondenceConfig(width=16, blocks=2, patches=64)),
        TrainingPreset(name="standard", steps=24_000),
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
    """Train (resuming ``run`` if it holds a finished checkpoint of the same preset) and return
    the checkpoint."""
    if run.exists():
        checkpoint = torch.load(run, weights_only=False)
        if checkpoint["preset"] == preset.name and checkpoint["step"] >= preset.steps:
            return checkpoint
    torch.manual_seed(seed)
    rng = np.random.default_rng(seed)
    template = Template.load(parts_dir / "template")
    centres, patch = template_patches(template.vertices, template.faces, preset.config.patches)
    model = CorrespondenceNet(preset.config, centres)
    parts = load_parts(parts_dir, "train")
    if not parts:
        raise FileNotFoundError(f"no training parts under {parts_dir / 'parts'}")
    inputs_of = [torch_inputs(part) for part in parts]
    stencils = [stencil_matrices(inputs[4], inputs[5]) for inputs in inputs_of]
    optimizer = torch.optim.Adam(model.parameters(), lr=preset.learning_rate)
    schedule = torch.optim.lr_scheduler.CosineAnnealingLR(optimizer, preset.steps)
    rest = torch.as_tensor(template.vertices, dtype=torch.float32)
    patch_of = torch.as_tensor(patch)
    losses, started = [], time.perf_counter()
    for step in range(preset.steps):
        chosen = int(rng.integers(len(parts)))
        part = parts[chosen]
        target = torch.as_tensor(part["target"])
        area = torch.as_tensor(part["mass"])
        area = area / area.sum()
        heads = model.heads(*inputs_of[chosen], stencils[chosen])
        position, _ = model.place(heads)
        scores = heads.logits
        classification = (torch.nn.functional.cross_entropy(scores, patch_of[target], reduction="none") * area).sum()
        place = (torch.linalg.norm(position - rest[target], dim=1) * area).sum()
        loss = classification + PLACE_WEIGHT * place
        optimizer.zero_grad()
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        optimizer.step()
        schedule.step()
        losses.append((float(classification), float(place)))
        if (step + 1) % max(preset.steps // 20, 1) == 0:
            recent = np.mean(losses[-max(preset.steps // 20, 1) :], axis=0)
            log(
                f"step {step + 1}/{preset.steps}: cross entropy {recent[0]:.3f}, place {100 * recent[1]:.1f} cm, "
                f"{time.perf_counter() - started:.0f} s"
            )
    checkpoint = {
        "model": model.state_dict(),
        "config": preset.config.as_dict(),
        "centres": centres,
        "patch": patch,
        "preset": preset.name,
        "training": asdict(preset) | {"config": preset.config.as_dict()},
        "seed": seed,
        "step": preset.steps,
        "losses": np.asarray(losses),
        "seconds": time.perf_counter() - started,
    }
    run.parent.mkdir(parents=True, exist_ok=True)
    torch.save(checkpoint, run)
    return checkpoint


def restored(checkpoint: dict) -> CorrespondenceNet:
    """The trained network of a checkpoint, in evaluation mode."""
    model = CorrespondenceNet(CorrespondenceConfig(**checkpoint["config"]), checkpoint["centres"])
    model.load_state_dict(checkpoint["model"])
    return model.eval()
