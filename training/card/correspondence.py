"""The model card's correspondence section, generated from ``models/correspondence.json``: parts
placed on the template beside the whole body, the spectral localizer and the rule's ceiling;
pairs' overlaps and unions beside the trivial answers; each goal met or not."""

from collections.abc import Callable

BEGIN, END = "<!-- correspondence:begin -->", "<!-- correspondence:end -->"
SET_NAMES = {
    "test_a": "A: seen people, unseen poses",
    "test_b": "B: unseen people, random regions",
    "test_c": "C: unseen people, camera views",
}
PLACING_GOAL_MS = 300  # a ~10 k-vertex part placed, its eigenbasis included
PAIR_NAMES = {"pairs_b": "B: region pairs, B in another pose", "pairs_c": "C: a session's views"}
# The union evaluation's overlap strata (training.data.pairs.STRATA), by the pair's true overlap.
STRATUM_NAMES = {
    "identical": "stratum: identical",
    "same_region": "stratum: the same region",
    "nested": "stratum: nested (≥ 98 % inside)",
    "over_75": "stratum: > 75 % shared",
    "25_to_75": "stratum: 25–75 % shared",
    "under_25": "stratum: < 25 % shared",
}


def render(metrics: dict, command: str) -> str:
    """The card's correspondence tables: parts beside the whole body and the spectral localizer,
    pairs' overlaps and unions beside the trivial answers, and the goals."""
    pairs = metrics["pairs"]
    lines = [
        BEGIN,
        f"Produced by `{command}`. {recipe_line(metrics['training'])}",
        "",
        "Parts placed on the template (means over parts; error: each vertex's place against its true rest-pose "
        "vertex, area-weighted; IoU area-weighted; coverage error: mean over the 16 body parts of the covered "
        "share's difference, points, as served: summed from each template vertex's covered share, the localizer's "
        "from its region; true places: the same region rule fed each vertex's true place, the most it can reach; "
        "relaxed: the places relaxed toward the part's own edge lengths, as /v1/correspondence?places=relaxed "
        "answers them (regions are read from the network's); warned: answered with the warning that the part's "
        "places are uncertain, its mean place confidence below "
        f"{pairs['uncertain_below']:.2f}, the least certain {pairs['uncertain_percentile']:g} % of the validation "
        "pairs' parts).",
        "",
        "| set | variant | parts | place error cm (centroid) | ≤ 5 / ≤ 10 cm | relaxed: error cm / ≤ 10 cm | flips "
        "| IoU / mirror-allowed | true places | whole body | spectral localizer (mirror-allowed) "
        "| coverage error (localizer) | warned |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, variants in metrics["parts"].items():
        for variant, row in variants.items():
            lines.append(
                f"| {SET_NAMES[name]} | {variant} | {row['parts']} | {row['error_cm']:.1f} "
                f"({row['centroid_error_cm']:.1f}) | {_pc(row['within_5'])} / {_pc(row['within_10'])} | "
                f"{row['relaxed_error_cm']:.1f} / {_pc(row['relaxed_within_10'])} | {_pc(row['flipped'])} | "
                f"{_pc(row['iou'])} / {_pc(row['iou_mirror'])} | "
                f"{_pc(row['true_places_iou'])} | {_pc(row['whole_body_iou'])} | {_pc(row['localizer_iou_mirror'])} | "
                f"{row['coverage_error']:.1f} ({row['localizer_coverage_error']:.1f}) | {_pc(row['warned'])} |"
            )
    lines += [
        "",
        "Pairs of parts of one person (union error: mean relative error of the 20 eigenvalues; told measured: "
        "the overlap and boundary share measured from the parts' regions; served: told them where the measured "
        f"overlap is below {pairs['tell_below']:g}, and told the pair nested (overlap 1) where every eigenvalue of "
        "one part is at least the other's and that part's mean place confidence is below "
        f"{pairs['nested_below']:g}: the thresholds whose unions erred least on {pairs['validation']['pairs']} "
        f"validation pairs of the training people ({_pc(pairs['validation']['served'])} there, against "
        f"{_pc(pairs['validation']['untold'])} untold and {_pc(pairs['validation']['told_measured'])} always told "
        "the measured shares)); each set by kind of pair, then by overlap stratum (the share of the smaller part "
        "inside the other, as the union's evaluation divides pairs):",
        "",
        "| set | kind or stratum | pairs | true overlap | overlap / boundary abs. error | told nested | "
        "union error untold / told measured / **served** / told truth | elementwise min | "
        "union IoU / mirror-allowed | whole body | spectral localizer |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, group, row in pair_groups(metrics, overall=True):
        lines.append(
            f"| {PAIR_NAMES[name]} | {group} | {row['pairs']} | {row['true_overlap']:.2f} | "
            f"{row['overlap_error']:.3f} / {row['boundary_error']:.3f} | {_pc(row['nested'])} | "
            f"{_pc(row['untold'])} / "
            f"{_pc(row['told_measured'])} / **{_pc(row['served'])}** / {_pc(row['told_truth'])} | "
            f"{_pc(row['elementwise_min'])} | "
            f"{_pc(row['iou'])} / {_pc(row['iou_mirror'])} | {_pc(row['whole_body_iou'])} | "
            f"{_pc(row['localizer_iou_mirror'])} |"
        )
    lines += [
        "",
        cost_line(metrics["cost"]),
        "",
        *goals(metrics),
        "",
        f"ONNX parity: {metrics['parity_max_relative']:.1e}.",
        END,
    ]
    return "\n".join(lines)


def recipe_line(training: dict) -> str:
    """The recipe the served weights were trained by, as the run recorded it (its checkpoint's
    preset), so the card cannot describe another network than the one served."""
    config = training["config"]
    restarts = training.get("restarts", [])
    schedule = f"{training['steps']:,} steps at learning rate {training['learning_rate']:g}".replace(",", " ")
    if restarts:
        schedule += ", then " + ", ".join(f"{steps:,} at {rate:g}".replace(",", " ") for steps, rate in restarts)
    return (
        f"Recipe (`{training['name']}`): {config['blocks']} DiffusionNet blocks of width {config['width']}, "
        f"{config['patches']} template patches, places averaged within {100 * config['neighbourhood_m']:g} cm, "
        f"offset at most {100 * config['offset_m']:g} cm; {schedule} (cosine cycles)."
    )


def cost_line(cost: dict) -> str:
    """What placing the sample part cost on the machine that ran the evaluation."""
    vertices, placed = (format(cost[key], ",").replace(",", " ") for key in ("vertices", "placed_vertices"))
    return (
        f"Placing a {vertices}-vertex part (`{cost['part']}`, the README's sample, through its copy of "
        f"{placed} vertices as the service places it) cost {cost['total_ms']:.0f} ms on the machine that ran this "
        f"evaluation, beyond its own spectrum: Laplacian {cost['laplacian_ms']:.0f}, the copy with its eigenbasis "
        f"and the other inputs {cost['inputs_ms']:.0f}, graph "
        f"{cost['graph_ms']:.0f}, region {cost['region_ms']:.0f}, on {cost['threads']} thread as a solver worker "
        "runs it (medians, stages in turns; `benchmarks/RESULTS.md` has three runs beside LaPy-CHOLMOD's "
        "eigenbasis)."
    )


def goals(metrics: dict) -> list[str]:
    """Each goal of the correspondence work against what was measured, met or not; a goal holds
    for every delivery of its test set (mesh, re-meshed, point cloud)."""
    parts, pairs = metrics["parts"], metrics["pairs"]["sets"]
    regions, views = parts["test_b"], parts["test_c"]
    groups = [row for _, _, row in pair_groups(metrics)]
    gap = worst_served_gap(metrics)
    checks = [
        ("part IoU ≥ 85 % (every B delivery)", *_every(regions, "iou", _pc, lambda x: x >= 0.85)),
        ("part IoU ≥ 85 % (every C delivery)", *_every(views, "iou", _pc, lambda x: x >= 0.85)),
        (
            "union IoU ≥ 85 % (every pair kind and stratum)",
            f"{_pc(min(r['iou'] for r in groups))} at worst",
            min(r["iou"] for r in groups) >= 0.85,
        ),
        ("coverage error ≤ 5 points (C)", *_every(views, "coverage_error", "{:.1f}".format, lambda x: x <= 5)),
        ("flips ≤ 5 % (C)", *_every(views, "flipped", _pc, lambda x: x <= 0.05)),
        ("place error ≤ 5 cm (C)", *_every(views, "error_cm", "{:.1f} cm".format, lambda x: x <= 5)),
        ("≥ 90 % within 10 cm (C)", *_every(views, "within_10", _pc, lambda x: x >= 0.9)),
        (
            "overlap abs. error ≤ 0.08 (C pairs)",
            f"{pairs['pairs_c']['all']['overlap_error']:.3f}",
            pairs["pairs_c"]["all"]["overlap_error"] <= 0.08,
        ),
        (
            "union of spectra told their places within 1 point of told truth (every kind and stratum)",
            f"{100 * gap:.1f} points at worst",
            gap <= 0.01,
        ),
    ]
    cost = metrics["cost"]
    checks.append(
        (
            f"a {cost['vertices'] // 1000} k-vertex part placed in ≤ {PLACING_GOAL_MS} ms, its eigenbasis included",
            f"{cost['total_ms']:.0f} ms",
            cost["total_ms"] <= PLACING_GOAL_MS,
        )
    )
    nested = nested_groups(metrics)
    if nested:
        checks.append(
            (
                "nested pairs no worse than the elementwise minimum",
                "; ".join(f"{label} {_pc(r['served'])} against {_pc(r['elementwise_min'])}" for label, r in nested),
                all(r["served"] <= r["elementwise_min"] for _, r in nested),
            )
        )
    lines = ["| goal | measured | met |", "|---|---|---|"]
    lines += [f"| {goal} | {measured} | {'yes' if met else '**no**'} |" for goal, measured, met in checks]
    return lines


def pair_groups(metrics: dict, overall: bool = False) -> list[tuple[str, str, dict]]:
    """(set, kind or stratum, summary row) of every test pair set: its kinds, then its overlap
    strata; with ``overall`` its mean over all pairs first."""
    pairs = metrics["pairs"]
    out = []
    for name, kinds in pairs["sets"].items():
        out += [(name, kind, row) for kind, row in kinds.items() if overall or kind != "all"]
        strata = pairs.get("strata", {}).get(name, {})
        out += [(name, label, strata[stratum]) for stratum, label in STRATUM_NAMES.items() if stratum in strata]
    return out


def nested_groups(metrics: dict) -> list[tuple[str, dict]]:
    """The pairs one of which lies inside the other: the close-ups inside their view, and each
    set's nested stratum."""
    pairs = metrics["pairs"]
    close_ups = pairs["sets"]["pairs_c"].get("camera_close_up")
    out = [] if close_ups is None else [("close-ups", close_ups)]
    for name, strata in pairs.get("strata", {}).items():
        if "nested" in strata:
            out.append((f"{name.removeprefix('pairs_').upper()} nested", strata["nested"]))
    return out


def worst_served_gap(metrics: dict) -> float:
    """How far the union as served is from told the true overlap, on the worst kind or stratum of pairs."""
    return max(row["served"] - row["told_truth"] for _, _, row in pair_groups(metrics))


def _every(rows: dict[str, dict], key: str, show: Callable[[float], str], holds: Callable[[float], bool]) -> tuple:
    """(measured, met) of a goal that holds for every delivery in ``rows`` (by variant name)."""
    measured = " / ".join(show(row[key]) for row in rows.values()) + f" ({' / '.join(rows)})"
    return measured, all(holds(row[key]) for row in rows.values())


def _pc(x: float) -> str:
    return f"{100 * x:.1f} %"
