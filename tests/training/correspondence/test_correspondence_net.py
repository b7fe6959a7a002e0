"""The correspondence network: its two gradient paths agree, it learns, and its ONNX graph matches
PyTorch on parts of other sizes than the one it was traced on (no anny: an irregular curved
patch, with no symmetry to hide a place, is the template)."""

import copy
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxscript")

from app.geometry.descriptors import mesh_inputs  # noqa: E402
from app.geometry.topology import drop_unreferenced, referenced  # noqa: E402
from app.inference.template import Template, faces_inside  # noqa: E402
from tests.conftest import bumpy_patch  # noqa: E402
from training.common.fit import OtherRecipe  # noqa: E402
from training.common.onnx_export import relative_difference  # noqa: E402
from training.correspondence.export import correspondence_parity, export_correspondence, training_path  # noqa: E402
from training.correspondence.net import CorrespondenceConfig, basis_gradient, stencil_matrices  # noqa: E402
from training.correspondence.train import TrainingPreset, restored, torch_inputs, train  # noqa: E402

CONFIG = CorrespondenceConfig(width=16, blocks=2, patches=24, neighbourhood_m=0.2, offset_m=0.05)


def _parts_dir(root: Path) -> Path:
    """A bumpy patch 0.6 m across as the template, and pieces of it (cut by lines at several
    angles) as parts whose every vertex's target is its own template vertex."""
    mesh = bumpy_patch(5, n=500)
    vertices = 0.3 * mesh.vertices
    template = Template(vertices, mesh.faces, np.zeros(len(vertices), int), np.arange(len(vertices)))
    template.save(root / "template", "a bumpy patch")
    (root / "parts").mkdir()
    for index, angle in enumerate((0.0, 1.5, 3.0, 4.5)):
        mask = vertices[:, :2] @ [np.cos(angle), np.sin(angle)] > -0.1
        inside = mesh.faces[faces_inside(mask, mesh.faces)]
        target = np.flatnonzero(referenced(inside, len(vertices)))
        part = mesh_inputs(*drop_unreferenced(vertices, inside), k=32)
        np.savez(root / "parts" / f"train-{index:05d}.npz", target=target, **part.feeds())
    return root


def test_the_basis_gradient_is_the_stencil_applied_to_each_function(tmp_path):
    """The exported graph's gathered gradient of the basis against the training path's sparse
    stencil, and its projection against the mass-weighted transpose, in float64: equal to rounding."""
    part = dict(np.load(next((_parts_dir(tmp_path) / "parts").glob("*.npz"))))
    basis, mass = (torch.as_tensor(part[name], dtype=torch.float64) for name in ("basis", "mass"))
    neighbours, weights = torch.as_tensor(part["neighbours"]), torch.as_tensor(part["weights"], dtype=torch.float64)
    taken = basis_gradient(basis, mass, neighbours, weights)
    stencil = stencil_matrices(neighbours, weights)
    torch.testing.assert_close(taken.x, torch.sparse.mm(stencil.x, basis), rtol=1e-12, atol=1e-12)
    torch.testing.assert_close(taken.y, torch.sparse.mm(stencil.y, basis), rtol=1e-12, atol=1e-12)
    assert min(taken.x.abs().max(), taken.y.abs().max()) > 1.0  # gradients, not zeros
    eye = torch.eye(basis.shape[1], dtype=torch.float64)
    torch.testing.assert_close(taken.projection @ basis, eye, rtol=0, atol=1e-5)  # M-orthonormal (stored in float32)


def test_the_sparse_stencil_and_the_basis_gradient_give_one_network(tmp_path):
    """Training applies the stencil to each block's diffused channels; the exported graph expands
    the basis's gradient by each block's coefficients: one network either way."""
    part = dict(np.load(next((_parts_dir(tmp_path) / "parts").glob("*.npz"))))
    from training.correspondence.net import CorrespondenceNet

    model = CorrespondenceNet(CONFIG, np.random.default_rng(0).normal(size=(CONFIG.patches, 3))).eval()
    inputs = torch_inputs(part)
    with torch.no_grad():
        gathered = model.heads(*inputs)
        sparse = model.heads(*inputs, stencil_matrices(inputs[4], inputs[5]))
    torch.testing.assert_close(sparse.logits, gathered.logits, rtol=1e-4, atol=1e-5)
    torch.testing.assert_close(sparse.offset, gathered.offset, rtol=1e-4, atol=1e-6)


def test_it_learns_and_its_graph_matches_pytorch_on_other_parts(tmp_path):
    parts_dir = _parts_dir(tmp_path)
    checkpoint = train(
        parts_dir,
        tmp_path / "run.pt",
        TrainingPreset(name="test", steps=400, learning_rate=5e-3, config=CONFIG),
        log=lambda _: None,
    )
    losses = checkpoint["losses"]
    first, last = losses[:20].mean(axis=0), losses[-20:].mean(axis=0)
    assert last[0] < 0.6 * first[0] and last[1] < 0.8 * first[1]  # cross entropy and place error fall
    model = restored(checkpoint)
    parts = [dict(np.load(path)) for path in sorted((parts_dir / "parts").glob("*.npz"))]
    export_correspondence(model, parts[0], tmp_path / "correspondence.onnx")
    graph_error = correspondence_parity(model, tmp_path / "correspondence.onnx", parts[1:])
    assert graph_error < 2 * float32_error(model, parts[1:]) and graph_error < 1e-3


def float32_error(model, parts: list[dict[str, np.ndarray]]) -> float:
    """How far the network itself, run in float32 as trained, is from its float64 answer: the
    rounding the exported graph (float32 too) cannot be asked to beat."""
    exact = copy.deepcopy(model).double()
    differences = (
        relative_difference(single, expected)
        for part in parts
        for single, expected in zip(training_path(model, part), training_path(exact, part), strict=True)
    )
    return max(differences)


def test_a_run_continued_after_its_first_cycle_ends_where_one_run_would(tmp_path):
    """Warm restarts: a checkpoint of the first cycle continued with the preset's next cycle has
    the weights and losses of the same preset trained from scratch (same parts drawn, a fresh
    Adam per cycle)."""
    parts_dir = _parts_dir(tmp_path)
    first = TrainingPreset(name="cycles", steps=6, learning_rate=5e-3, config=CONFIG)
    both = TrainingPreset(name="cycles", steps=6, learning_rate=5e-3, restarts=((4, 1e-3),), config=CONFIG)
    quiet = {"log": lambda _: None}
    train(parts_dir, tmp_path / "continued.pt", first, **quiet)
    continued = train(parts_dir, tmp_path / "continued.pt", both, **quiet)
    scratch = train(parts_dir, tmp_path / "scratch.pt", both, **quiet)
    assert continued["step"] == scratch["step"] == 10
    np.testing.assert_array_equal(continued["losses"], scratch["losses"])
    for name, weights in scratch["model"].items():
        torch.testing.assert_close(continued["model"][name], weights, rtol=0, atol=0)


def test_a_run_stopped_in_a_later_cycle_keeps_the_cycles_it_finished(tmp_path):
    """Each cycle's end is saved: a run stopped inside its second cycle leaves the first cycle's
    checkpoint, and the same command then ends where one uninterrupted run does."""
    parts_dir = _parts_dir(tmp_path)
    preset = TrainingPreset(name="cycles", steps=6, learning_rate=5e-3, restarts=((4, 1e-3),), config=CONFIG)

    class Stopped(Exception):
        pass

    def stop_in_second_cycle(line: str) -> None:
        if "(from 0.001)" in line:
            raise Stopped

    with pytest.raises(Stopped):
        train(parts_dir, tmp_path / "stopped.pt", preset, log=stop_in_second_cycle)
    assert torch.load(tmp_path / "stopped.pt", weights_only=False)["step"] == 6
    continued = train(parts_dir, tmp_path / "stopped.pt", preset, log=lambda _: None)
    scratch = train(parts_dir, tmp_path / "scratch.pt", preset, log=lambda _: None)
    np.testing.assert_array_equal(continued["losses"], scratch["losses"])
    for name, weights in scratch["model"].items():
        torch.testing.assert_close(continued["model"][name], weights, rtol=0, atol=0)


def test_a_checkpoint_of_another_recipe_is_refused_not_taken_as_finished(tmp_path):
    """A finished run of one width, asked for again under the same preset name at another width
    (or another seed), is neither returned as if it were that recipe's nor overwritten."""
    parts_dir = _parts_dir(tmp_path)
    narrow = TrainingPreset(name="cycles", steps=4, learning_rate=5e-3, config=CONFIG)
    wider = TrainingPreset(name="cycles", steps=4, learning_rate=5e-3, config=replace(CONFIG, width=CONFIG.width * 2))
    quiet = {"log": lambda _: None}
    finished = train(parts_dir, tmp_path / "run.pt", narrow, **quiet)
    with pytest.raises(OtherRecipe):
        train(parts_dir, tmp_path / "run.pt", wider, **quiet)
    with pytest.raises(OtherRecipe):
        train(parts_dir, tmp_path / "run.pt", narrow, seed=1, **quiet)
    assert train(parts_dir, tmp_path / "run.pt", narrow, **quiet)["step"] == finished["step"] == 4
    assert torch.load(tmp_path / "run.pt", weights_only=False)["config"]["width"] == CONFIG.width
