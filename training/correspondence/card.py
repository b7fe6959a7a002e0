"""The model card's correspondence section, generated from ``models/correspondence.json``: parts
placed on the template beside the whole body, the spectral localizer and the rule's ceiling;
pairs' overlaps and unions beside the trivial answers; each goal met or not."""

BEGIN, END = "<!-- correspondence:begin -->", "<!-- correspondence:end -->"
SET_NAMES = {
    "test_a": "A: seen people, unseen poses",
    "test_b": "B: unseen people, random regions",
    "test_c": "C: unseen people, camera views",
}
PAIR_NAMES = {"pairs_b": "B: region pairs, B in another pose", "pairs_c": "C: a session's views"}


def render(metrics: dict, command: str) -> str:
    """The card's correspondence tables: parts beside the whole body and the spectral localizer,
    pairs' overlaps and unions beside the trivial answers, and the goals."""
    lines = [
        BEGIN,
        f"Produced by `{command}`.",
        "",
        "Parts placed on the template (means over parts; error: each vertex's place against its true rest-pose "
        "vertex, area-weighted; IoU area-weighted; coverage error: mean over the 16 body parts of the covered "
        "share's difference, points; true places: the same region rule fed each vertex's true place, the most it "
        "can reach).",
        "",
        "| set | variant | parts | place error cm (centroid) | ≤ 5 / ≤ 10 cm | flips | IoU / mirror-allowed "
        "| true places | whole body | spectral localizer (mirror-allowed) | coverage error (localizer) |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for name, variants in metrics["parts"].items():
        for variant, row in variants.items():
            lines.append(
                f"| {SET_NAMES[name]} | {variant} | {row['parts']} | {row['error_cm']:.1f} "
                f"({row['centroid_error_cm']:.1f}) | {_pc(row['within_5'])} / {_pc(row['within_10'])} | "
                f"{_pc(row['flipped'])} | {_pc(row['iou'])} / {_pc(row['iou_mirror'])} | "
                f"{_pc(row['true_places_iou'])} | {_pc(row['whole_body_iou'])} | {_pc(row['localizer_iou_mirror'])} | "
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
    """Each goal of the correspondence work against what was measured, met or not; a goal holds
    for every delivery of its test set (mesh, re-meshed, point cloud)."""
    parts, pairs = metrics["parts"], metrics["pairs"]["sets"]
    views = parts["test_c"]
    union_rows = [row for kinds in pairs.values() for kind, row in kinds.items() if kind != "all"]
    nested = pairs["pairs_c"].get("camera_close_up")

    def every_view(key: str, show, rows: dict = views) -> str:
        return " / ".join(show(row[key]) for row in rows.values()) + f" ({' / '.join(rows)})"

    def centimetres(x: float) -> str:
        return f"{x:.1f} cm"

    def points(x: float) -> str:
        return f"{x:.1f}"

    regions = parts["test_b"]
    checks = [
        (
            "part IoU ≥ 85 % (every B delivery)",
            every_view("iou", _pc, regions),
            all(r["iou"] >= 0.85 for r in regions.values()),
        ),
        ("part IoU ≥ 85 % (every C delivery)", every_view("iou", _pc), all(r["iou"] >= 0.85 for r in views.values())),
        (
            "union IoU ≥ 85 % (every pair kind)",
            f"{_pc(min(r['iou'] for r in union_rows))} at worst",
            min(r["iou"] for r in union_rows) >= 0.85,
        ),
        (
            "coverage error ≤ 5 points (C)",
            every_view("coverage_error", points),
            all(r["coverage_error"] <= 5 for r in views.values()),
        ),
        ("flips ≤ 5 % (C)", every_view("flipped", _pc), all(r["flipped"] <= 0.05 for r in views.values())),
        (
            "place error ≤ 5 cm (C)",
            every_view("error_cm", centimetres),
            all(r["error_cm"] <= 5 for r in views.values()),
        ),
        (
            "≥ 90 % within 10 cm (C)",
            every_view("within_10", _pc),
            all(r["within_10"] >= 0.9 for r in views.values()),
        ),
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
