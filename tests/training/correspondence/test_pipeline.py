"""``make correspondence PRESET=tiny`` end to end: anny parts and pairs → training → ONNX →
evaluation → card, in under a minute (needs the train extra: torch, anny, onnxscript).

A few steps only: what is checked is the plumbing the served graph goes through — the service
verifies and loads what the pipeline wrote, every pair is counted once per kind and once per
overlap stratum, and the thresholds the card names are the graph's.
"""

import json
import shutil
from pathlib import Path

import pytest

pytest.importorskip("torch")
pytest.importorskip("anny")
pytest.importorskip("onnxscript")

import onnx  # noqa: E402

from app.contract import CORRESPONDENCE_FILE  # noqa: E402
from app.geometry.laplacian import mesh_operators  # noqa: E402
from app.geometry.placing import mesh_part  # noqa: E402
from app.inference.correspondence import TELL_BELOW_KEY, CorrespondenceModel  # noqa: E402
from app.inference.manifest import verify_manifest  # noqa: E402
from app.inference.models import SpectralModels  # noqa: E402
from app.inference.nesting import NESTED_BELOW_KEY  # noqa: E402
from app.samples import PARTS, template_part_mesh  # noqa: E402
from training.card.correspondence import BEGIN, END, render  # noqa: E402
from training.correspondence.evaluate import NESTED_THRESHOLDS, TELL_THRESHOLDS  # noqa: E402
from training.correspondence.pairs import PAIR_SETS, build_pairs  # noqa: E402
from training.correspondence.parts import PARTS_PRESETS, build_parts  # noqa: E402
from training.correspondence.pipeline import METRICS_FILE, run_correspondence_pipeline  # noqa: E402

SERVED = Path(__file__).resolve().parents[3] / "models"


@pytest.fixture(scope="module")
def pipeline(tmp_path_factory):
    root = tmp_path_factory.mktemp("correspondence")
    models = root / "models"
    shutil.copytree(SERVED, models)
    preset = PARTS_PRESETS["tiny"]
    build_parts(preset, root / "parts", seed=0, workers=1)
    build_pairs(preset, root / "parts", seed=0, workers=1)
    metrics = run_correspondence_pipeline(root / "parts", root / "runs", models, "tiny", 0, "test")
    return models, metrics


def test_the_service_verifies_and_places_with_what_the_pipeline_wrote(pipeline):
    """The manifest records the new graph, and it places the README's part: every vertex on the
    template, with a confidence."""
    models, _ = pipeline
    assert CORRESPONDENCE_FILE in verify_manifest(models)
    served = SpectralModels(models)
    model = CorrespondenceModel(models / CORRESPONDENCE_FILE, served.template_regions)
    sample = template_part_mesh(served.template, PARTS["no_head_neck.ply"])
    part = mesh_part(sample.vertices, sample.faces, mesh_operators(sample.vertices, sample.faces))
    placement = model.place(part)
    vertices = len(served.template.vertices)
    assert placement.vertex.shape == (len(sample.vertices),) and placement.vertex.max() < vertices
    assert 0 < placement.mean_confidence <= 1


def test_every_test_pair_is_counted_once_by_kind_and_once_by_stratum(pipeline):
    _, metrics = pipeline
    pairs = metrics["pairs"]
    for name in PAIR_SETS:
        kinds, strata = pairs["sets"][name], pairs["strata"][name]
        total = kinds["all"]["pairs"]
        assert total > 0
        assert sum(row["pairs"] for kind, row in kinds.items() if kind != "all") == total
        assert sum(row["pairs"] for row in strata.values()) == total


def test_the_card_and_the_graph_say_the_same_thresholds(pipeline):
    models, metrics = pipeline
    card = (models / "MODEL_CARD.md").read_text()
    written = json.loads((models / METRICS_FILE).read_text())
    assert card[card.index(BEGIN) : card.index(END) + len(END)] == render(written, "test")
    props = {entry.key: entry.value for entry in onnx.load(str(models / CORRESPONDENCE_FILE)).metadata_props}
    assert float(props[TELL_BELOW_KEY]) == metrics["pairs"]["tell_below"] in TELL_THRESHOLDS
    assert float(props[NESTED_BELOW_KEY]) == metrics["pairs"]["nested_below"] in NESTED_THRESHOLDS
    assert metrics["parity_max_relative"] < 1e-3
