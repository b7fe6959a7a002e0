"""From a parts build to ``models/correspondence.onnx``: train, export, check parity, evaluate.

The figures go to ``models/correspondence.json`` and their own section of the model card (the
union pipeline's ``metrics.json`` and section are left as they are); the manifest is rewritten
so the service verifies and serves the new graph.
"""

import json
import time
from pathlib import Path

import onnx

from app.contract import CORRESPONDENCE_FILE
from app.inference import NESTED_BELOW_KEY, TELL_BELOW_KEY, UNCERTAIN_BELOW_KEY, write_manifest
from training.card.correspondence import BEGIN, END, render
from training.card.glance import update_glance
from training.card.tables import replace_block
from training.correspondence.cost import part_cost
from training.correspondence.evaluate import evaluate_correspondence, evaluate_pairs
from training.correspondence.export import correspondence_parity, export_correspondence
from training.correspondence.train import TRAINING_PRESETS, load_parts, restored, train

METRICS_FILE = "correspondence.json"


def run_correspondence_pipeline(
    parts_dir: Path, runs: Path, models: Path, preset: str, seed: int, command: str
) -> dict:
    started = time.perf_counter()
    checkpoint = train(parts_dir, runs / f"correspondence-{preset}.pt", TRAINING_PRESETS[preset], seed)
    model = restored(checkpoint)
    trained = time.perf_counter()
    graph = models / CORRESPONDENCE_FILE
    checks = load_parts(parts_dir, "test_c")[:4]
    export_correspondence(model, checks[0], graph)
    write_manifest(models)
    metrics = served_figures(parts_dir, models) | {
        "parity_max_relative": correspondence_parity(model, graph, checks),
        "training": checkpoint["training"] | {"seconds": round(checkpoint["seconds"], 1)},
        "build": json.loads((parts_dir / "parts.json").read_text()),
        "seconds": {"training": round(trained - started, 1), "total": round(time.perf_counter() - started, 1)},
    }
    write_figures(models, metrics, command)
    return metrics


def reevaluate_correspondence(parts_dir: Path, models: Path, command: str) -> dict:
    """The served graph's figures again without training it, after a change to how parts are
    placed: its thresholds re-chosen and every part, pair and cost re-scored on ``parts_dir``'s
    test and validation draws (which a build draws the same with or without its training parts);
    what the training recorded (recipe, parity, build, time) stays."""
    metrics = json.loads((models / METRICS_FILE).read_text()) | served_figures(parts_dir, models)
    write_figures(models, metrics, command)
    return metrics


def served_figures(parts_dir: Path, models: Path) -> dict:
    """The served graph's thresholds chosen on the validation pairs and written into it, then
    its parts, pairs and placing cost scored."""
    graph = models / CORRESPONDENCE_FILE
    pairs = evaluate_pairs(parts_dir, graph, models)
    set_thresholds(graph, pairs["tell_below"], pairs["nested_below"], pairs["uncertain_below"])
    write_manifest(models)
    return {
        "parts": evaluate_correspondence(parts_dir, graph, models),
        "pairs": pairs,
        "cost": part_cost(graph, models),
    }


def write_figures(models: Path, metrics: dict, command: str) -> None:
    """``models/correspondence.json``, the card's correspondence section and its glance."""
    (models / METRICS_FILE).write_text(json.dumps(metrics, indent=1))
    replace_block(models / "MODEL_CARD.md", BEGIN, END, render(metrics, command))
    update_glance(models)


def set_thresholds(graph: Path, tell_below: float, nested_below: float, uncertain_below: float) -> None:
    """Record in the graph's metadata below which measured overlap a union step is told it,
    below which place confidence a step whose spectra allow nesting is told nested, and below
    which a part's places are called uncertain (what the service reads:
    :data:`app.inference.correspondence.TELL_BELOW_KEY`, :data:`app.inference.nesting.NESTED_BELOW_KEY`,
    :data:`app.inference.correspondence.UNCERTAIN_BELOW_KEY`)."""
    model = onnx.load(str(graph))
    props = {entry.key: entry.value for entry in model.metadata_props}
    props |= {
        TELL_BELOW_KEY: repr(tell_below),
        NESTED_BELOW_KEY: repr(nested_below),
        UNCERTAIN_BELOW_KEY: repr(uncertain_below),
    }
    onnx.helper.set_model_props(model, props)
    onnx.save(model, str(graph))
