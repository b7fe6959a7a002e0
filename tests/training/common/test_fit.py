"""The one training loop both trainers use: it learns, resumes exactly, stops early, clips."""

from dataclasses import replace

import pytest

torch = pytest.importorskip("torch")

from training.common.fit import (  # noqa: E402
    LoopSettings,
    Objective,
    OtherRecipe,
    fit,
    seed_everything,
    validation_history,
)

SETTINGS = LoopSettings(epochs=10, batch=8, learning_rate=0.1, weight_decay=0.0, first_restart=10, patience=10)


def _run(tmp_path, settings: LoopSettings, validation=None, name: str = "run.pt"):
    """A line fitted to y = 3x − 1 by the loop; returns the model and its final mean squared error."""
    generator = seed_everything(0)
    x = torch.linspace(-1, 1, 64)[:, None]
    y = 3 * x - 1
    model = torch.nn.Linear(1, 1)

    def batch_loss(rows: torch.Tensor) -> torch.Tensor:
        noisy = x[rows] + 0.01 * torch.randn(x[rows].shape, generator=generator)  # the run's own stream
        return (model(noisy) - y[rows]).pow(2).mean()

    def score() -> float:
        with torch.no_grad():
            return float((model(x) - y).pow(2).mean())

    objective = Objective("line", len(x), batch_loss, validation or score, lambda value: f"{value:.4f}")
    fit(model, objective, settings, tmp_path / name, {"test": True}, generator)
    return model, score()


def test_the_loop_learns_and_keeps_the_best_epoch(tmp_path):
    model, final = _run(tmp_path, SETTINGS)
    assert final < 0.05  # it starts near 10
    assert abs(float(model.weight) - 3) < 0.3


def test_a_run_resumed_from_its_checkpoint_ends_where_an_uninterrupted_one_does(tmp_path):
    whole, _ = _run(tmp_path, SETTINGS, name="whole.pt")
    _run(tmp_path, replace(SETTINGS, epochs=4), name="split.pt")  # stopped after 4 epochs
    resumed, _ = _run(tmp_path, SETTINGS, name="split.pt")
    assert torch.equal(whole.weight, resumed.weight) and torch.equal(whole.bias, resumed.bias)


def test_validation_that_never_improves_stops_the_run_after_patience_epochs(tmp_path):
    calls = []

    def flat() -> float:
        calls.append(1)
        return 1.0

    _run(tmp_path, replace(SETTINGS, epochs=50, patience=2), validation=flat)
    assert len(calls) == 3  # the first epoch is the best, then two without a better one


@pytest.mark.parametrize("clip_norm", [0.05, None])
def test_clip_norm_bounds_the_gradient_the_optimizer_receives(tmp_path, clip_norm):
    # One step: Adam's first moment is then (1 − β₁) times the gradient it was given.
    one_step = replace(SETTINGS, epochs=1, batch=64, clip_norm=clip_norm)
    _run(tmp_path, one_step)
    state = torch.load(tmp_path / "run.pt", weights_only=False)["optimizer"]["state"]
    given = sum(float(s["exp_avg"].pow(2).sum()) for s in state.values()) ** 0.5 / 0.1
    if clip_norm is None:
        assert given > 1.0  # the raw gradient of this line is large
    else:
        assert given == pytest.approx(clip_norm, rel=1e-4)


def _line_run(tmp_path, settings: LoopSettings, config: dict) -> None:
    """A few epochs of the line's fit checkpointed at run.pt, under ``config``."""
    generator = seed_everything(0)
    model = torch.nn.Linear(1, 1)
    x = torch.linspace(-1, 1, 16)[:, None]

    def batch_loss(rows: torch.Tensor) -> torch.Tensor:
        return (model(x[rows]) - 2 * x[rows]).pow(2).mean()

    objective = Objective("line", len(x), batch_loss, lambda: 1.0, str)
    fit(model, objective, settings, tmp_path / "run.pt", config, generator)


def test_a_checkpoint_of_another_recipe_is_refused_naming_the_difference(tmp_path):
    short = replace(SETTINGS, epochs=2)
    _line_run(tmp_path, short, {"model": {"width": 8}, "training": {"epochs": 2, "seed": 0}})
    with pytest.raises(OtherRecipe, match="model.width: 8 there, 16 here"):
        _line_run(tmp_path, SETTINGS, {"model": {"width": 16}, "training": {"epochs": 10, "seed": 0}})
    with pytest.raises(OtherRecipe, match="training.seed"):
        _line_run(tmp_path, SETTINGS, {"model": {"width": 8}, "training": {"epochs": 10, "seed": 1}})


def test_the_same_recipe_trained_longer_continues(tmp_path):
    _line_run(tmp_path, replace(SETTINGS, epochs=2), {"model": {"width": 8}, "training": {"epochs": 2}})
    _line_run(tmp_path, replace(SETTINGS, epochs=4), {"model": {"width": 8}, "training": {"epochs": 4}})
    assert len(validation_history(tmp_path / "run.pt")) == 4
