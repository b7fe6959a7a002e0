"""Train → export → evaluate on the tiny synthetic data set (needs torch and onnxscript).

A few steps only: what is checked is the plumbing the real models go through — ONNX parity
with PyTorch, exact commutativity and monotone outputs of the exported operator, the
localizer's size, the tables, and that a checkpoint resumes instead of starting over.
"""

import json
from dataclasses import replace

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxscript")

from app.contract import UNKNOWN_BOUNDARY, UNKNOWN_OVERLAP, union_feeds  # noqa: E402
from app.inference.models import graph_inputs  # noqa: E402
from tests.training.data.synthetic import SyntheticSource  # noqa: E402
from training.common.data import SpectralData  # noqa: E402
from training.data.build import build_dataset  # noqa: E402
from training.data.presets import PRESETS  # noqa: E402
from training.reconstruction.train import partial_rows  # noqa: E402
from training.union import train as union_training  # noqa: E402
from training.union.export import session  # noqa: E402
from training.union.pipeline import TRAINING_PRESETS, run_pipeline  # noqa: E402
from training.union.predict import memory_rows  # noqa: E402
from training.union.train import SIZE_BINS, size_weights, train_union, union_kin  # noqa: E402


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("pipeline")
    build_dataset(SyntheticSource(), PRESETS["tiny"], root / "data", seed=0, workers=1)
    metrics = run_pipeline(root / "data", root / "runs", root / "models", TRAINING_PRESETS["tiny"], 0, "test")
    return root, metrics


def test_union_kin_are_the_pairs_whose_unions_overlap_by_test_b_s_threshold(trained):
    """Against the exact area IoU of the template masks (as they are or mirrored), away from the
    threshold (kin are judged on a sample of the vertices); whole-body unions have none."""
    root, _ = trained
    data = SpectralData(root / "data")
    rows = np.flatnonzero(data.pairs.split == "train")
    kin = union_kin(data, rows, rows).toarray()
    full = data.pairs.scenario[rows] == "full"
    assert not kin[full].any() and not kin[:, full].any() and kin[~full][:, ~full].diagonal().all()
    masks = data.masks(data.pairs.mask_union[rows[~full]]).astype(float)
    weights, mirror = data.vertex_area, data.template.mirror
    shared = np.maximum((masks * weights) @ masks.T, (masks * weights) @ masks[:, mirror].T)
    areas = masks @ weights
    iou = shared / (areas[:, None] + areas[None, :] - shared)
    clear = np.abs(iou - 0.8) > 0.05
    assert 0 < kin[~full][:, ~full][clear].sum() < clear.sum()
    np.testing.assert_array_equal(kin[~full][:, ~full][clear], iou[clear] >= 0.8)


def test_size_weights_keep_the_whole_body_share_and_draw_every_size_bin_alike(trained):
    root, _ = trained
    data = SpectralData(root / "data")
    rows = memory_rows(data)
    weights = size_weights(data, rows)
    whole = data.pairs.scenario[rows] == "full"
    share = data.mask_area(data.pairs.mask_union[rows]) / data.vertex_area.sum()
    bins = np.minimum((share * SIZE_BINS).astype(int), SIZE_BINS - 1)[~whole]
    per_bin = np.bincount(bins, weights=weights[~whole], minlength=SIZE_BINS)
    assert weights.sum() == pytest.approx(1.0) and weights[whole].sum() == pytest.approx(whole.mean())
    assert len(np.unique(bins)) >= 3
    np.testing.assert_allclose(per_bin[np.unique(bins)], (~whole).mean() / len(np.unique(bins)))


def test_training_hides_each_row_s_union_kin_from_its_memory(trained, tmp_path, monkeypatch):
    """With every row chosen (a share of 1), what a training row's memory hides is exactly its
    own body's rows and its union's kin: each batch row's hidden set is one of those."""
    root, _ = trained
    data = SpectralData(root / "data")
    rows = memory_rows(data)
    bodies = data.pairs.shape_a[rows]
    expected = (bodies[:, None] == bodies[None, :]) | union_kin(data, rows, rows).toarray()
    seen = []
    losses = union_training._losses

    def spy(model, pairs, hidden, chains, loss, overlap=None):
        seen.append(hidden.cpu().numpy())
        return losses(model, pairs, hidden, chains, loss, overlap)

    monkeypatch.setattr(union_training, "_losses", spy)
    settings = replace(TRAINING_PRESETS["tiny"].union, epochs=1, hide_union_type=1.0)
    train_union(data, tmp_path / "union.pt", settings)
    hidden = np.concatenate(seen)
    assert len(hidden) >= len(rows) - settings.batch  # an epoch's whole batches
    assert all((expected == row).all(axis=1).any() for row in hidden)
    same_body_only = bodies[:, None] == bodies[None, :]
    assert any(not (same_body_only == row).all(axis=1).any() for row in hidden)  # kin beyond the body


def test_the_decoder_s_partial_rows_are_training_unions_with_a_boundary(trained):
    """What the decoder learns partial unions from: spectra of unions that have a boundary (a
    Dirichlet λ₁ well above a closed body's 0), of people the operator trains on, at most as many
    as asked."""
    root, _ = trained
    data = SpectralData(root / "data")
    spectra, identity = partial_rows(data, 10, seed=0)
    assert 0 < len(spectra) <= 10 and len(spectra) == len(identity)
    assert (spectra[:, 0] > 1e-3 * spectra[:, 1]).all()
    pairs = data.pairs
    trained_people = data.identity_of(pairs.shape_a[pairs.split == "train"])
    assert np.isin(identity, trained_people).all()


def test_overlap_shares_are_whole_for_a_part_with_itself_or_inside_the_body_and_told_noisily(trained):
    """The share of the smaller part inside the other: 1 for a part with itself and for any part
    with the whole body (mask 0), between 0 and 1 for every pair; what training tells a batch
    (train_union._told) is that share within a few noise widths, or unknown, in about the
    preset's proportions."""
    root, _ = trained
    data = SpectralData(root / "data")
    pairs = data.pairs
    shares = data.overlap_shares(pairs.mask_a, pairs.mask_b)
    itself = pairs.mask_a == pairs.mask_b
    with_body = (pairs.mask_a == 0) | (pairs.mask_b == 0)
    assert itself.any() and with_body.any() and not (itself | with_body).all()
    np.testing.assert_allclose(shares[itself | with_body], 1.0, rtol=1e-12)
    assert ((shares >= 0) & (shares <= 1 + 1e-12)).all() and (shares < 0.9).any()
    settings = TRAINING_PRESETS["standard"].union
    many = torch.as_tensor(np.resize(shares, 20_000), dtype=torch.float32)
    told = union_training._told(many, settings, torch.Generator().manual_seed(0))[:, 0]
    known = told >= 0
    assert (told[~known] == UNKNOWN_OVERLAP).all()
    assert abs(known.float().mean().item() - settings.overlap_told) < 0.02
    assert ((told[known] - many[known]).abs() <= 5 * settings.overlap_noise).all()
    assert ((told[known] >= 0) & (told[known] <= 1)).all()


def test_onnx_matches_pytorch(trained):
    _, metrics = trained
    assert metrics["parity_max_relative"]["union"] <= 1e-4
    assert metrics["parity_max_relative"]["localizer"] <= 1e-4


def test_exported_union_commutes_is_non_decreasing_and_below_both_parts(trained):
    root, _ = trained
    union = session(root / "models" / "union.onnx")
    reads = graph_inputs(union)
    data = np.load(root / "data" / "dataset.npz")
    a = data["spectra"][data["spec_a"]].astype(np.float32)
    b = data["spectra"][data["spec_b"]].astype(np.float32)
    spectral = SpectralData(root / "data")
    overlap = spectral.overlap_shares(data["mask_a"], data["mask_b"])
    overlap[::3] = UNKNOWN_OVERLAP
    boundary = spectral.boundary_shares(data["mask_a"], data["mask_b"], data["mask_union"])  # as the preset reads it
    boundary[1::2] = UNKNOWN_BOUNDARY
    ab, sigma = union.run(None, union_feeds(reads, a, b, overlap, boundary))
    ba, _ = union.run(None, union_feeds(reads, b, a, overlap, boundary))
    assert np.max(np.abs(ab - ba)) <= 1e-6
    assert (np.diff(ab, axis=1) >= 0).all() and (sigma > 0).all()
    # A closed body's λ₁ is a numerical zero, sometimes −1e-13: the union's is clipped to 0.
    assert (ab <= np.maximum(np.minimum(a, b), 0) * (1 + 1e-6)).all()
    scaled, _ = union.run(None, union_feeds(reads, 4 * a, 4 * b, overlap, boundary))
    np.testing.assert_allclose(scaled, 4 * ab, rtol=1e-5)


def test_the_exported_folder_is_what_the_service_loads(trained):
    from app.inference.models import SpectralModels

    root, _ = trained
    models = SpectralModels(root / "models")  # checksums verified, template and graphs agree
    assert models.k == 20 and len(models.template.vertices) == models.vertex_area.shape[0]


def test_localizer_fits_the_budget(trained):
    root, _ = trained
    path = root / "models" / "localizer.onnx"
    assert path.stat().st_size <= 10 * 2**20
    (probability,) = session(path).run(None, {"spectrum": np.linspace(1, 80, 20, dtype=np.float32)[None]})
    assert probability.shape[0] == 1 and ((probability >= 0) & (probability <= 1)).all()


def test_tables_cover_the_test_rows(trained):
    root, metrics = trained
    written = json.loads((root / "models" / "metrics.json").read_text())
    assert written["rows"].keys() == metrics["rows"].keys()
    assert any(key.startswith("test_a/") for key in written["rows"])
    row = next(iter(written["rows"].values()))
    assert {"operator", "elementwise_min", "disjoint_union", "larger_part", "lookup"} <= set(row["union"])
    tables = (root / "models" / "EVALUATION.md").read_text()
    assert "| test_a/known_man/mesh |" in tables and "| λ20 |" in tables
    card = (root / "models" / "MODEL_CARD.md").read_text()
    assert any(key.startswith("test_c/") for key in written["strata"]) and "| camera_same |" in card
    assert "<!-- glance:begin -->\n| what | measured | goal | met |" in card
    assert {"3", "4", "5", "associativity"} <= set(written["test_c_chains"])


def test_scoring_the_exported_models_gives_the_trained_figures(trained, tmp_path):
    """`score` reads only the ONNX graphs: on the same data it must find what training found."""
    from typer.testing import CliRunner

    from training.cli import cli

    root, metrics = trained
    out = tmp_path / "scores.json"
    arguments = ["score", "--data", str(root / "data"), "--models", str(root / "models"), "--out", str(out)]
    result = CliRunner().invoke(cli, arguments)
    assert result.exit_code == 0, result.output
    scores = json.loads(out.read_text())
    for table in ("rows", "strata"):
        assert scores[table].keys() == metrics[table].keys()
        for key, row in metrics[table].items():
            expected = row["union"]["operator"]["mae"]
            assert abs(scores[table][key]["union"]["operator"]["mae"] - expected) <= 1e-3 * max(expected, 1), key


def test_a_killed_run_resumes_where_it_stopped(trained, tmp_path):
    """One epoch, then a resumed second, gives the very weights of two epochs in one go."""
    root, _ = trained
    data = SpectralData(root / "data")
    settings = replace(TRAINING_PRESETS["tiny"].union, epochs=2)
    straight = train_union(data, tmp_path / "straight.pt", settings)
    train_union(data, tmp_path / "resumed.pt", replace(settings, epochs=1))
    resumed = train_union(data, tmp_path / "resumed.pt", settings)
    for name, value in straight.state_dict().items():
        torch.testing.assert_close(resumed.state_dict()[name], value, rtol=0, atol=0, msg=name)
    state = torch.load(tmp_path / "resumed.pt", weights_only=False)
    assert state["epoch"] == 2
    assert {"weights", "optimizer", "config", "best_metric", "best_weights"} <= set(state)


def test_resuming_an_early_stopped_run_trains_nothing(trained, tmp_path):
    """A run stopped by its patience is loaded as it is: no extra epoch on resume."""
    root, _ = trained
    data = SpectralData(root / "data")
    settings = replace(TRAINING_PRESETS["tiny"].union, epochs=3, patience=0)  # stops after epoch 1
    first = train_union(data, tmp_path / "union.pt", settings)
    again = train_union(data, tmp_path / "union.pt", settings)
    for name, value in first.state_dict().items():
        torch.testing.assert_close(again.state_dict()[name], value, rtol=0, atol=0, msg=name)
    assert torch.load(tmp_path / "union.pt", weights_only=False)["epoch"] == 1


def test_evaluate_reproduces_the_trained_figures_and_refuses_unfinished_runs(trained, tmp_path):
    from typer.testing import CliRunner

    from training.cli import cli

    root, metrics = trained
    again = run_pipeline(
        root / "data", root / "runs", tmp_path / "models", TRAINING_PRESETS["tiny"], 0, "test", train=False
    )
    assert again["rows"] == metrics["rows"] and again["chains"] == metrics["chains"]
    empty = tmp_path / "no-runs"
    arguments = ["evaluate", "--data", str(root / "data"), "--runs", str(empty), "--preset", "tiny"]
    result = CliRunner().invoke(cli, [*arguments, "--models", str(tmp_path / "unused")])
    assert result.exit_code == 2 and "not trained to the end" in result.output
    assert not (tmp_path / "unused").exists() and not empty.exists()
