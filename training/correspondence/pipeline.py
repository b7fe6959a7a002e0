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
from app.inference.correspondence import TELL_BELOW_KEY
from app.inference.manifest import write_manifest
from training.correspondence.evaluate import evaluate_correspondence, evaluate_pairs
from training.correspondence.export import correspondence_parity, export_correspondence
from training.correspondence.train import TRAINING_PRESETS, load_parts, restored, train
from training.glance import update_glance
from training.learning.card import replace_block

METRICS_FILE = "correspondence.json"
BEGIN, END = "<!-- correspondence:begin -->", "<!-- correspondence:end -->"
SET_NAMES = {
    "test_a": "A: seen people, unseen poses",
    "test_b": "B: unseen people, random regions",
    "test_c": "C: unseen people, camera views",
}
PAIR_NAMES = {"pairs_b": "B: region pairs, B in another pose", "pairs_c": "C: a session's views"}


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
    pairs = evaluate_pairs(parts_dir, graph, models)
    set_tell_below(graph, pairs["tell_below"])
    write_manifest(models)
    metrics = {
        "parts": evaluate_correspondence(parts_dir, graph, models),
        "pairs": pairs,
        "parity_max_relative": correspondence_parity(model, graph, checks),
        "training": checkpoint["training"] | {"seconds": round(checkpoint["seconds"], 1)},
        "build": json.loads((parts_dir / "parts.json").read_text()),
        "seconds": {"training": round(trained - started, 1), "total": round(time.perf_counter() - started, 1)},
    }
    (models / METRICS_FILE).write_text(json.dumps(metrics, indent=1))
    replace_block(models / "MODEL_CARD.md", BEGIN, END, render(metrics, command))
    update_glance(models)
    return metrics


def set_tell_below(graph: Path, threshold: float) -> None:
    """Record in the graph's metadata below which measured overlap a union step is told it
    (what the service reads, :data:`app.inference.correspondence.TELL_BELOW_KEY`)."""
    model = onnx.load(str(graph))
    props = {entry.key: entry.value for entry in model.metadata_props} | {TELL_BELOW_KEY: repr(threshold)}
    onnx.helper.set_model_props(model, props)
    onnx.save(model, str(graph))


def render(metrics: dict, command: str) -> str:
    """The card's correspondence tables: parts beside the whole body and the spectral localizer,
    pairs' overlaps and unions beside the trivial answers, and the goals."""
    lines = [
        BEGIN,
        f"Produced by `{command}`.",
        "",
        "Parts placed on the template (means over parts; error: each vertex's place against its true rest-pose "
        "vertex, area-weighted; IoU area-weighted; coverage error: mean over the 16 body parts of the covered "
        "share's difference, points).",
        "",
        "| set | variant | parts | place error cm (centroid) | ≤ 5 / ≤ 10 cm | flips | IoU / mirror-allowed "
        "| whole body | spectral localizer (mirror-allowed) | coverage error (localizer) |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, variants in metrics["parts"].items():
        for variant, row in variants.items():
            lines.append(
                f"| {SET_NAMES[name]} | {variant} | {row['parts']} | {row['error_cm']:.1f} "
                f"({row['centroid_error_cm']:.1f}) | {_pc(row['within_5'])} / {_pc(row['within_10'])} | "
                f"{_pc(row['flipped'])} | {_pc(row['iou'])} / {_pc(row['iou_mirror'])} | "
                f"{_pc(row['whole_body_iou'])} | {_pc(row['localizer_iou_mirror'])} | "
                f"{row['coverage_error']:.1f} ({row['localizer_coverage_error']:.1f}) |"
            )
    pairs = metrics["pairs"]
    lines += [
        "",
        "Pairs of parts of one person (union error: mean relative error of the 20 eigenvalues; told measured: "
        "the overlap and boundary share measured from the parts' regions; served: told them where the measured "
        f"overlap is below {pairs['tell_below']:g}, the threshold whose unions erred least on "
        f"{pairs['validation']['pairs']} validation pairs of the training people ({_pc(pairs['validation']['served'])} "
        f"there, against {_pc(pairs['validation']['untold'])} untold and {_pc(pairs['validation']['told_measured'])} "
        "always told)):",
        "",
        "| set | kind | pairs | true overlap | overlap / boundary abs. error | union error untold / told measured / "
        "**served** / told truth | elementwise min | union IoU / mirror-allowed | whole body | spectral localizer |",
        "|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, kinds in pairs["sets"].items():
        for kind, row in kinds.items():
            lines.append(
                f"| {PAIR_NAMES[name]} | {kind} | {row['pairs']} | {row['true_overlap']:.2f} | "
                f"{row['overlap_error']:.3f} / {row['boundary_error']:.3f} | {_pc(row['untold'])} / "
                f"{_pc(row['told_measured'])} / **{_pc(row['served'])}** / {_pc(row['told_truth'])} | "
                f"{_pc(row['elementwise_min'])} | "
                f"{_pc(row['iou'])} / {_pc(row['iou_mirror'])} | {_pc(row['whole_body_iou'])} | "
                f"{_pc(row['localizer_iou_mirror'])} |"
            )
    lines += ["", *goals(metrics), "", f"ONNX parity: {metrics['parity_max_relative']:.1e}.", END]
    return "\n".join(lines)


def goals(metrics: dict) -> list[str]:
    """Each goal of the correspondence work against what was measured, met or not."""
    parts, pairs = metrics["parts"], metrics["pairs"]["sets"]
    camera = parts["test_c"]["mesh"]
    region_sets = [parts["test_b"]["mesh"], parts["test_c"]["mesh"]]
    union_rows = [row for kinds in pairs.values() for kind, row in kinds.items() if kind != "all"]
    nested = pairs["pairs_c"].get("camera_close_up")
    checks = [
        (
            "part IoU ≥ 85 % (B, C meshes)",
            " / ".join(_pc(s["iou"]) for s in region_sets),
            all(s["iou"] >= 0.85 for s in region_sets),
        ),
        (
            "union IoU ≥ 85 % (every pair kind)",
            f"{_pc(min(r['iou'] for r in union_rows))} at worst",
            min(r["iou"] for r in union_rows) >= 0.85,
        ),
        ("coverage error ≤ 5 points (C)", f"{camera['coverage_error']:.1f}", camera["coverage_error"] <= 5),
        ("flips ≤ 5 % (C)", _pc(camera["flipped"]), camera["flipped"] <= 0.05),
        ("place error ≤ 5 cm (C)", f"{camera['error_cm']:.1f} cm", camera["error_cm"] <= 5),
        ("≥ 90 % within 10 cm (C)", _pc(camera["within_10"]), camera["within_10"] >= 0.9),
        (
            "overlap abs. error ≤ 0.08 (C pairs)",
            f"{pairs['pairs_c']['all']['overlap_error']:.3f}",
            pairs["pairs_c"]["all"]["overlap_error"] <= 0.08,
        ),
        (
            "union as served within 1 point of told truth (every kind)",
            f"{100 * max(r['served'] - r['told_truth'] for r in union_rows):.1f} points at worst",
            all(r["served"] - r["told_truth"] <= 0.01 for r in union_rows),
        ),
    ]
    if nested is not None:
        checks.append(
            (
                "nested pairs no worse than the elementwise minimum",
                f"{_pc(nested['served'])} against {_pc(nested['elementwise_min'])}",
                nested["served"] <= nested["elementwise_min"],
            )
        )
    lines = ["| goal | measured | met |", "|---|---|---|"]
    lines += [f"| {goal} | {measured} | {'yes' if met else '**no**'} |" for goal, measured, met in checks]
    return lines


def _pc(x: float) -> str:
    return f"{100 * x:.1f} %"
