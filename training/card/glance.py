"""The model card's at-a-glance table: every served model's headline figures against their goals,
read from the metrics files the three training commands write, so that the card's first table
is as current as its last.

Each command rewrites it after its own section (``update_glance``); a metrics file not there
yet (a fresh clone trains one model at a time), or a figure it does not hold (a tiny data set has
no re-meshed Test C stratum), leaves its rows out rather than guessing them.
"""

import json
from collections.abc import Callable
from pathlib import Path

from training.card.correspondence import PLACING_GOAL_MS, worst_served_gap
from training.card.tables import percent, replace_block
from training.sessions import body_card
from training.sessions import card as sessions_card

BEGIN, END = "<!-- glance:begin -->", "<!-- glance:end -->"
CARD = "MODEL_CARD.md"
Row = tuple[str, str, str, bool | None]  # what, measured, goal, met (None: no goal)


def _span(values: list[float]) -> str:
    low, high = min(values), max(values)
    return percent(low) if round(100 * low, 1) == round(100 * high, 1) else f"{100 * low:.1f}–{100 * high:.1f} %"


def _both(metrics: dict, key: str) -> tuple[float, float]:
    """A Test C stratum's operator error untold and told the share."""
    told = metrics["overlap_told"][key]["union"]["told"]["mre"]
    return metrics["strata"][key]["union"]["operator"]["mre"], told


def same_region_row(metrics: dict) -> Row:
    same = [_both(metrics, f"test_c/same_region/{v}") for v in ("mesh", "remeshed")]
    return (
        "U(A, A′): one region in another pose / meshing (Test C), untold; told",
        f"{percent(same[0][0])} / {percent(same[1][0])}; {percent(same[0][1])} / {percent(same[1][1])}",
        "≤ 2 %",
        max(told for _, told in same) <= 0.02,
    )


def nested_row(metrics: dict) -> Row:
    nested = [_both(metrics, f"test_c/nested/{v}") for v in ("mesh", "remeshed")]
    floor = [metrics["strata"][f"test_c/nested/{v}"]["union"]["elementwise_min"]["mre"] for v in ("mesh", "remeshed")]
    return (
        "nested pairs (Test C mesh / re-meshed), untold; told",
        f"{percent(nested[0][0])} / {percent(nested[1][0])}; {percent(nested[0][1])} / {percent(nested[1][1])}",
        f"≤ the elementwise minimum ({percent(floor[0])} / {percent(floor[1])})",
        all(n[1] <= f for n, f in zip(nested, floor, strict=True)),
    )


def shared_row(metrics: dict) -> Row:
    shares = [_both(metrics, f"test_c/{s}/mesh") for s in ("over_75", "25_to_75", "under_25")]
    return (
        "Test C > 75 / 25–75 / < 25 % shared (mesh), untold; told",
        " / ".join(percent(u) for u, _ in shares) + "; " + " / ".join(percent(t) for _, t in shares),
        "≤ 10 %",
        all(t <= 0.10 for _, t in shares),
    )


def _test_b(metrics: dict) -> list[str]:
    """Test B's mesh and re-meshed rows (the point-cloud rows hold 6–14 pairs each)."""
    keys = [key for key in metrics["rows"] if key.startswith("test_b/") and not key.endswith("/cloud")]
    if not keys:
        raise KeyError("test_b")
    return keys


def unseen_types_row(metrics: dict) -> Row:
    rows, told = metrics["rows"], metrics["overlap_told"]
    keys = _test_b(metrics)
    untold = [rows[k]["union"]["operator"]["mre"] for k in keys]
    told_both = [told[k]["union"]["told_boundary"]["mre"] for k in keys]
    disjoint = [rows[k]["union"]["disjoint_union"]["mre"] for k in keys]
    return (
        "Test B (unions never trained on), mesh and re-meshed rows, untold; told both shares",
        f"{_span(untold)}; {_span(told_both)}",
        f"≤ 10 % (the disjoint union: {_span(disjoint)})",
        max(told_both) <= 0.10,
    )


def sessions_row(metrics: dict) -> Row:
    chains = metrics["test_c_chains"]
    lengths = [n for n in chains if n != "associativity"]
    return (
        f"sessions of {' / '.join(lengths)} camera views, untold; told each step",
        " / ".join(percent(chains[n]["union"]["operator"]["mre"]) for n in lengths)
        + "; "
        + " / ".join(percent(chains[n]["union"]["operator_told_boundary"]["mre"]) for n in lengths),
        "—",
        None,
    )


def coverage_row(metrics: dict) -> Row:
    keys = _test_b(metrics)
    coverage = [metrics["rows"][k]["interval_coverage"] for k in keys]
    told = [metrics["overlap_told"][k]["interval_coverage"]["told"] for k in keys]
    return (
        "90 % interval's coverage, Test B rows, untold; told",
        f"{_span(coverage)}; {_span(told)}",
        "87–93 %",
        all(0.87 <= c <= 0.93 for c in coverage + told),
    )


def spectral_region_row(metrics: dict) -> Row:
    located = [
        metrics["rows"][k]["localization"]["union_with_parts"]["iou"] for k in _test_b(metrics) if "child" not in k
    ]
    return ("region from a spectrum alone (Test B adults, IoU)", _span(located), "≥ 80 %", min(located) >= 0.80)


def identity_row(metrics: dict) -> Row:
    retrieval = metrics["retrieval"]
    return (
        "identity top-1 from two parts covering the body, untold (share profile); told",
        f"{percent(retrieval['operator_union_share_profile']['top1'])}; "
        f"{percent(retrieval['operator_union_told']['top1'])}",
        f"≥ 85 % (complete shapes: {percent(retrieval['shapedna_complete']['top1'])})",
        retrieval["operator_union_told"]["top1"] >= 0.85,
    )


def decoder_row(metrics: dict) -> Row:
    """The shape decoder's row (``reconstruction.json``)."""
    sets = metrics["sets"]
    goals = (("true_spectrum", 10.0), ("two_part_union", 15.0), ("session_chain", 15.0))
    measured = [sets[name]["decoder"]["vertex_mean_mm"] for name, _ in goals]
    return (
        "body rebuilt from the true spectrum / a two-part union / a 5-view session (mean vertex error)",
        " / ".join(f"{m:.1f}" for m in measured) + " mm",
        " / ".join(f"≤ {g:.0f}" for _, g in goals) + " mm",
        all(m <= g for m, (_, g) in zip(measured, goals, strict=True)),
    )


def camera_region_row(metrics: dict) -> Row:
    """A camera view placed by the correspondence model (``correspondence.json``), beside the whole body."""
    parts = metrics["parts"]["test_c"]
    camera = [parts[v]["iou"] for v in ("mesh", "remeshed", "cloud")]
    return (
        "uploaded camera view's region (Test C mesh / re-meshed / cloud, IoU)",
        " / ".join(percent(x) for x in camera),
        f"≥ 85 % (the whole body: {percent(parts['mesh']['whole_body_iou'])})",
        min(camera) >= 0.85,
    )


def random_region_row(metrics: dict) -> Row:
    iou = metrics["parts"]["test_b"]["mesh"]["iou"]
    return ("uploaded random region's region (Test B mesh, IoU)", percent(iou), "≥ 85 %", iou >= 0.85)


def part_coverage_row(metrics: dict) -> Row:
    """Judged on every delivery of a camera view, as the goal is set."""
    errors = [metrics["parts"]["test_c"][v]["coverage_error"] for v in ("mesh", "remeshed", "cloud")]
    return (
        "per-part coverage error, camera views (Test C mesh / re-meshed / cloud)",
        " / ".join(f"{e:.1f}" for e in errors) + " points",
        "≤ 5 points",
        max(errors) <= 5,
    )


def session_pair_row(metrics: dict) -> Row:
    """Judged as the goal is set: the union within a point of told the truth on every kind and
    overlap stratum of a session's pairs and on Test B's, not on their mean alone."""
    session = metrics["pairs"]["sets"]["pairs_c"]["all"]
    gap = worst_served_gap(metrics)
    return (
        "a session's two views as spectra with region tokens: overlap error; union (told the truth; "
        "worst kind's or stratum's gap)",
        f"{session['overlap_error']:.3f}; {percent(session['served'])} ({percent(session['told_truth'])}; "
        f"{100 * gap:.1f} points)",
        "≤ 0.08; within 1 point of told the truth, every kind, stratum and Test B",
        session["overlap_error"] <= 0.08 and gap <= 0.01,
    )


def scanning_session_row(metrics: dict) -> Row:
    """A scanning session's union as /v1/sessions answers it, worst over lengths and deliveries."""
    span = sessions_card.lengths(metrics)
    met = sessions_card.goals(metrics)
    return (
        f"a scanning session's union, {span[0]}–{span[-1]} views (Test C people), unregistered / registered",
        f"worst {percent(sessions_card.worst(metrics, 'unregistered'))} / "
        f"{percent(sessions_card.worst(metrics, 'registered'))}",
        f"≤ {100 * sessions_card.GOAL_ANY:.0f} % / ≤ {100 * sessions_card.GOAL_REGISTERED:.0f} % at every length",
        all(met.values()),
    )


def session_body_row(metrics: dict) -> Row:
    """The body fitted to a 5-view session, registered and not, against the goal."""
    rows = metrics["evaluation"]
    registered, unregistered = rows["5/registered"]["vertex_mm"], rows["5/unregistered"]["vertex_mm"]
    return (
        "the body fitted to a 5-view session (Test C people), registered / unregistered (mean vertex error)",
        f"{registered:.1f} / {unregistered:.1f} mm",
        f"≤ {body_card.GOAL_BODY_MM:.0f} mm",
        max(registered, unregistered) <= body_card.GOAL_BODY_MM,
    )


def session_identity_row(metrics: dict) -> Row:
    """The person scanned answered first from a 5-view session (its fitted body), against the goal."""
    identity = metrics["evaluation"]["5/registered"]["identity"]
    return (
        "identity from a 5-view session (Test C people among the seed database), first; before (union decoded)",
        f"{percent(identity['top1'])}; {percent(identity['today_top1'])}",
        f"≥ {100 * body_card.GOAL_IDENTITY:.0f} %",
        identity["top1"] >= body_card.GOAL_IDENTITY,
    )


def placing_cost_row(metrics: dict) -> Row:
    """What the evaluation measured placing the sample part cost, on the machine that ran it."""
    cost = metrics["cost"]
    return (
        f"placing a {cost['vertices'] // 1000} k-vertex part, its eigenbasis included "
        f"({cost['threads']} thread, as served)",
        f"{cost['total_ms']:.0f} ms",
        f"≤ {PLACING_GOAL_MS} ms",
        cost["total_ms"] <= PLACING_GOAL_MS,
    )


SOURCES: tuple[tuple[str, tuple[Callable[[dict], Row], ...]], ...] = (
    (
        "metrics.json",
        (
            same_region_row,
            nested_row,
            shared_row,
            unseen_types_row,
            sessions_row,
            coverage_row,
            spectral_region_row,
            identity_row,
        ),
    ),
    (
        "correspondence.json",
        (camera_region_row, random_region_row, part_coverage_row, session_pair_row, placing_cost_row),
    ),
    ("reconstruction.json", (decoder_row,)),
    ("sessions.json", (scanning_session_row,)),
    ("bodies.json", (session_body_row, session_identity_row)),
)


def rows_of(metrics: dict, rows: tuple[Callable[[dict], Row], ...]) -> list[Row]:
    """Each row whose figures the metrics hold."""
    out = []
    for row in rows:
        try:
            out.append(row(metrics))
        except KeyError:
            continue
    return out


def render_glance(models: Path) -> str:
    """The block: one row per headline figure of every model whose metrics are in ``models``."""
    lines = [BEGIN, "| what | measured | goal | met |", "|---|---|---|---|"]
    for name, rows in SOURCES:
        path = models / name
        if not path.exists():
            continue
        for what, measured, goal, met in rows_of(json.loads(path.read_text()), rows):
            verdict = "—" if met is None else ("yes" if met else "**no**")
            lines.append(f"| {what} | {measured} | {goal} | {verdict} |")
    lines.append(END)
    return "\n".join(lines)


def update_glance(models: Path) -> None:
    """Rewrite the card's at-a-glance block from the metrics files in ``models``."""
    replace_block(models / CARD, BEGIN, END, render_glance(models))
