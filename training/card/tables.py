"""Render metrics.json as tables: every table in ``EVALUATION.md`` beside the models, and their
summary in ``MODEL_CARD.md``.

The card's prose is written by hand; its generated tables live between two markers so that
re-running the evaluation refreshes the figures without touching the text around them.
"""

from pathlib import Path

import numpy as np

from training.localizer.masks import UNION_WITH_PARTS

BEGIN, END = "<!-- metrics:begin -->", "<!-- metrics:end -->"
CARD, EVALUATION = "MODEL_CARD.md", "EVALUATION.md"
PAPER_ROWS = [
    f"{split}/{group}/{variant}"
    for split in ("test_a", "test_b")
    for variant in ("mesh", "remeshed")
    for group in ("known_man", "unknown_man", "unknown_woman")
]
BASELINES = ("elementwise_min", "disjoint_union", "larger_part", "lookup")


def percent(x: float) -> str:
    return f"{100 * x:.1f} %"


def union_table(metrics: dict) -> list[str]:
    paper = metrics["paper"]["union"]
    lines = [
        "| row | n | paper mse / mae | operator mse / mae / mre | 90 % interval coverage | "
        + " | ".join(f"{b} mae / mre" for b in BASELINES)
        + " |",
        "|---" * (5 + len(BASELINES)) + "|",
    ]
    rows = metrics["rows"]
    ordered = PAPER_ROWS + sorted(set(rows) - set(PAPER_ROWS))
    for key in ordered:
        if key not in rows:
            continue
        row = rows[key]
        ours = row["union"]["operator"]
        paper_cell = "{:.2f} / {:.2f}".format(*paper[key]) if key in paper else "—"
        baselines = " | ".join(f"{row['union'][b]['mae']:.2f} / {percent(row['union'][b]['mre'])}" for b in BASELINES)
        lines.append(
            f"| {key} | {row['rows']} | {paper_cell} | "
            f"{ours['mse']:.2f} / {ours['mae']:.2f} / {percent(ours['mre'])} | "
            f"{percent(row['interval_coverage'])} | {baselines} |"
        )
    return lines


def per_eigenvalue_table(metrics: dict, methods: tuple[str, ...] = ("operator", "lookup")) -> list[str]:
    """Mean relative error by eigenvalue index, pooled over the paper's rows of each split."""
    columns = [(split, method) for split in ("test_a", "test_b") for method in methods]
    pooled = {}
    for split, method in columns:
        rows = [metrics["rows"][key] for key in PAPER_ROWS if key.startswith(split) and key in metrics["rows"]]
        curves = [row["union"][method]["mre_per_eigenvalue"] for row in rows]
        pooled[split, method] = np.average(curves, axis=0, weights=[row["rows"] for row in rows])
    lines = [
        "| eigenvalue | " + " | ".join(f"{split} {method}" for split, method in columns) + " |",
        "|---" * (len(columns) + 1) + "|",
    ]
    for index in range(len(next(iter(pooled.values())))):
        cells = " | ".join(percent(pooled[column][index]) for column in columns)
        lines.append(f"| λ{index + 1} | {cells} |")
    return lines


def localization_table(metrics: dict) -> list[str]:
    names = sorted({name for row in metrics["rows"].values() for name in row["localization"]})
    paper = metrics["paper"]["localization"]
    header = "| row | " + " | ".join(f"{n}: IoU / acc. / part cov. err." for n in names) + " | paper one / six: IoU |"
    lines = [header, "|---" * (len(names) + 2) + "|"]
    for key in PAPER_ROWS:
        row = metrics["rows"].get(key)
        if row is None:
            continue
        cells = " | ".join(_localization_cell(row["localization"][n], ("iou", "accuracy")) for n in names)
        reference = f"{paper['one'][key][0]:.2f} % / {paper['six'][key][0]:.2f} %"
        lines.append(f"| {key} | {cells} | {reference} |")
    return lines


def _localization_cell(scores: dict, names: tuple[str, ...]) -> str:
    """The named scores in percent, then the part-coverage error in points."""
    return " / ".join([*(percent(scores[name]) for name in names), f"{100 * scores['coverage_error']:.1f} pt"])


def extra_table(metrics: dict) -> list[str]:
    chains, floor = metrics["chains"], metrics["noise_floor"]
    lines = ["| case | n | method | mse | mae | mre | 90 % coverage |", "|---|---|---|---|---|---|---|"]
    for name, errors in chains.get("union", {}).items():
        covered = percent(chains["interval_coverage"]) if name == "operator" and "interval_coverage" in chains else "—"
        lines.append(
            f"| chain (A∪B)∪C | {chains['rows']} | {name} | {errors['mse']:.2f} | {errors['mae']:.2f} | "
            f"{percent(errors['mre'])} | {covered} |"
        )
    lines.append(
        f"| pose noise floor | {floor['rows']} | same region, other pose | {floor['mse']:.2f} | {floor['mae']:.2f} | "
        f"{percent(floor['mre'])} | — |"
    )
    return lines


def strata_table(metrics: dict) -> list[str]:
    """Overlap strata of Test C (camera sessions) and of Test A's overlapping pairs."""
    lines = [
        "| split / stratum / variant | n | operator mae / mre | 90 % coverage | above min | "
        + " | ".join(f"{b} mre" for b in BASELINES)
        + " | best baseline ÷ operator | served region (/v1/localize): IoU / part cov. err. |",
        "|---" * (7 + len(BASELINES)) + "|",
    ]
    for key, row in metrics.get("strata", {}).items():
        union = row["union"]
        ours = union["operator"]
        best = min(union[b]["mre"] for b in BASELINES)
        ratio = f"{best / ours['mre']:.2f}×" if ours["mre"] > 0 else "exact"
        lines.append(
            f"| {key} | {row['rows']} | {ours['mae']:.2f} / {percent(ours['mre'])} | "
            f"{percent(row['interval_coverage'])} | {percent(row['above_minimum'])} | "
            + " | ".join(percent(union[b]["mre"]) for b in BASELINES)
            + f" | {ratio} | {_localization_cell(row['localization'][UNION_WITH_PARTS], ('iou',))} |"
        )
    return lines


# The answers of the told table: name in metrics, column title (boundary columns where the operator reads it).
TOLD_ANSWERS = (
    ("not_told", "not told"),
    ("told", "told"),
    ("told_noisy", "told ± 0.1"),
    ("told_boundary", "told + boundary share"),
    ("told_boundary_noisy", "told ± 0.1 + boundary ± 0.06"),
)


def told_table(metrics: dict) -> list[str]:
    """Test C strata and Test B groups with the operator told each pair's overlap (exactly, and as
    measured: ± 0.1), and its boundary share too where it reads one, beside it not told and the
    best baseline on the same rows; then Test C's chains told each step likewise."""
    told = metrics.get("overlap_told", {})
    if not told:
        return []
    answers = [(name, title) for name, title in TOLD_ANSWERS if name in next(iter(told.values()))["union"]]
    lines = [
        "| split / stratum or group / variant | n | "
        + " | ".join(f"{title} mre" for _, title in answers)
        + " | best baseline mre | 90 % coverage: "
        + " / ".join(title for _, title in answers)
        + " |",
        "|---" * (len(answers) + 4) + "|",
    ]
    for key, row in told.items():
        union, coverage = row["union"], row["interval_coverage"]
        same_rows = metrics.get("strata", {}).get(key) or metrics["rows"].get(key)
        best = min(same_rows["union"][b]["mre"] for b in BASELINES) if same_rows else float("nan")
        lines.append(
            f"| {key} | {row['rows']} | "
            + " | ".join(percent(union[name]["mre"]) for name, _ in answers)
            + f" | {percent(best)} | "
            + " / ".join(percent(coverage[name]) for name, _ in answers)
            + " |"
        )
    chained = {"not_told": "operator", "told": "operator_told", "told_boundary": "operator_told_boundary"}
    for length, row in metrics.get("test_c_chains", {}).items():
        if "operator_told" in row.get("union", {}):
            union = row["union"]
            best = min(union[b]["mre"] for b in BASELINES if b in union)
            cells = [percent(union[chained[name]]["mre"]) if chained.get(name) in union else "—" for name, _ in answers]
            lines.append(
                f"| test_c / chain of {length} views, each step told | {row['rows']} | "
                + " | ".join(cells)
                + f" | {percent(best)} | — |"
            )
    return lines


def session_table(metrics: dict) -> list[str]:
    """Test C by kind of session pair, then its chains of consecutive views."""
    methods = ("operator", *BASELINES)
    lines = [
        "| Test C pair kind / chain | n | "
        + " | ".join(f"{m} mre" for m in methods)
        + " | 90 % coverage | served region (/v1/localize): IoU / part cov. err. |",
        "|---" * (len(methods) + 4) + "|",
    ]
    for kind, row in metrics.get("test_c_kinds", {}).items():
        cells = " | ".join(percent(row["union"][m]["mre"]) for m in methods)
        lines.append(f"| {kind} | {row['rows']} | {cells} | — | (by overlap stratum) |")
    chains = metrics.get("test_c_chains", {})
    for length, row in chains.items():
        if length == "associativity":
            continue
        cells = " | ".join(percent(row["union"][m]["mre"]) if m in row["union"] else "—" for m in methods)
        region = row.get("localization", {}).get(UNION_WITH_PARTS)
        located = "—" if region is None else _localization_cell(region, ("iou",))
        lines.append(
            f"| chain of {length} views | {row['rows']} | {cells} | {percent(row['interval_coverage'])} | {located} |"
        )
    if "associativity" in chains:
        gap = chains["associativity"]
        lines += [
            "",
            f"Associativity on {gap['rows']} chains of views 0, 1, 2: mean relative gap between (A ∪ B) ∪ C and "
            f"A ∪ (B ∪ C) of {percent(gap['mean_relative_gap'])} (λ₂…λ₂₀).",
        ]
    return lines


def retrieval_table(metrics: dict) -> list[str]:
    paper = {"operator_union": "86.14 / 97.75 / 99.20 %", "shapedna_complete": "86.59 / 96.81 / 97.72 %"}
    lines = ["| query | n | top-1 / 5 / 10 | paper |", "|---|---|---|---|"]
    for name, row in metrics.get("retrieval", {}).items():
        rates = " / ".join(f"{100 * row[f'top{t}']:.1f}" for t in (1, 5, 10))
        lines.append(f"| {name} | {row['queries']} | {rates} % | {paper.get(name, '—')} |")
    return lines


def render(metrics: dict, command: str) -> str:
    """Every table of the evaluation, for ``EVALUATION.md`` beside the models."""
    validation = metrics["union_validation"]
    lines = [
        "# Evaluation of the union operator and the localizers",
        "",
        f"Generated from `metrics.json` by `{command}`; the model card summarizes it. Rows are",
        "`split/group/variant`: Test A (poses or regions unseen; the union type may be seen), Test B (a union",
        "whose symmetric IoU with every training union is below 0.8), Test C (scanning sessions of people never",
        "trained on); `mesh` the extracted submesh, `remeshed` 30 % of its vertices collapsed, `cloud` points",
        "with flagged boundaries. Baselines on the same rows: the elementwise minimum, the disjoint union (the k",
        "smallest of both spectra), the larger part, and the nearest training pair's union (lookup). mre: mean",
        "relative error per eigenvalue (a closed union's λ₁ = 0 left out).",
        "",
        "## Union spectrum (the paper's Table 1)",
        "mse/mae in (1/m²)², 1/m².",
        "",
        *union_table(metrics),
        "",
        "Mean relative error by eigenvalue, pooled over the 6 paper rows of each split:",
        "",
        *per_eigenvalue_table(metrics),
        "",
        "## Localization (the paper's Tables 2 and 3): symmetric, area-weighted",
        "Each column a localizer on the predicted union at p ≥ 0.5 (`all` is the served one), but `parts_united`:",
        f"the served localizer on each part, the two regions united; and `{UNION_WITH_PARTS}`, what `/v1/localize`",
        "answers for spectra: each region the most probable vertices up to the area the served localizer",
        "expects, the union's grown to hold each part's own (turned to its side).",
        "",
        *localization_table(metrics),
        "",
        "## Overlap strata",
        "Stratum: share of the smaller part inside the other. identical = one spectrum twice; same_region = the",
        "region again in another pose or meshing; nested ≥ 98 %. above min: share of eigenvalues above",
        "min(λ(A), λ(B)), which a union cannot be.",
        "",
        *strata_table(metrics),
        "",
        *session_table(metrics),
        "",
        *_told_section(metrics),
        "## Chains and the noise floor",
        "",
        *extra_table(metrics),
        "",
        f"Union operator, validation {validation['metric']} per epoch (the lowest is kept): "
        + ", ".join(f"{m:.4g}" for m in validation["per_epoch"]),
        "",
        "## Identity retrieval (the paper's Table 4)",
        *RETRIEVAL_NOTE,
        "",
        *retrieval_table(metrics),
        "",
    ]
    return "\n".join(lines)


RETRIEVAL_NOTE = (
    "Queries: the full-coverage test pairs (every group and variant); database: every complete posed body",
    "of the benchmark except the query's own shape (ShapeDNA: each complete shape against the others).",
    "`operator_union_share_profile`: the same unions untold, each stored shape at its distance to the nearest",
    "of the unions told each share 0, 0.1, …, 1 (as `/v1/retrieve` ranks two operands whose union is closed).",
)


def summary_table(metrics: dict) -> list[str]:
    """Per split and variant, pooled over groups: the operator untold and told, its interval's
    coverage, the baselines, and the served spectral region."""
    told = metrics.get("overlap_told", {})
    lines = [
        "| rows | n | operator mre, untold / told | 90 % coverage | "
        + " / ".join(BASELINES)
        + " mre | region from the spectrum: IoU / part cov. err. |",
        "|---|---|---|---|---|---|",
    ]
    groups: dict[str, list[str]] = {}
    for key in metrics["rows"]:
        split, _, variant = key.split("/")
        groups.setdefault(f"{split}/{variant}", []).append(key)
    for name, keys in sorted(groups.items()):
        rows = [metrics["rows"][k] for k in keys]
        weights = [r["rows"] for r in rows]

        def pooled(values: list[float], weights: list[int] = weights) -> float:
            return float(np.average(values, weights=weights))

        untold = percent(pooled([r["union"]["operator"]["mre"] for r in rows]))
        told_keys = [k for k in keys if k in told]
        if told_keys:
            told_mre = pooled(
                [told[k]["union"]["told"]["mre"] for k in told_keys], [told[k]["rows"] for k in told_keys]
            )
            untold += f" / {percent(told_mre)}"
        region = [r["localization"][UNION_WITH_PARTS] for r in rows]
        lines.append(
            f"| {name} | {sum(weights)} | {untold} | {percent(pooled([r['interval_coverage'] for r in rows]))} | "
            + " / ".join(percent(pooled([r["union"][b]["mre"] for r in rows])) for b in BASELINES)
            + f" | {percent(pooled([x['iou'] for x in region]))} / "
            f"{100 * pooled([x['coverage_error'] for x in region]):.1f} pt |"
        )
    return lines


def test_c_strata_table(metrics: dict) -> list[str]:
    """Test C's overlap strata: the operator untold and told beside the best baseline, and its
    interval's coverage untold."""
    told = metrics.get("overlap_told", {})
    lines = [
        "| Test C stratum / variant | n | operator mre, untold / told | best baseline mre | 90 % coverage |",
        "|---|---|---|---|---|",
    ]
    for key, row in metrics.get("strata", {}).items():
        if not key.startswith("test_c/"):
            continue
        union = row["union"]
        answer = percent(union["operator"]["mre"])
        if key in told:
            answer += f" / {percent(told[key]['union']['told']['mre'])}"
        best = min(BASELINES, key=lambda b: union[b]["mre"])
        lines.append(
            f"| {key.removeprefix('test_c/')} | {row['rows']} | {answer} | {percent(union[best]['mre'])} ({best}) | "
            f"{percent(row['interval_coverage'])} |"
        )
    return lines


def render_summary(metrics: dict, command: str) -> str:
    """The card's section: the union and localization figures pooled, every table in EVALUATION.md."""
    lines = [
        BEGIN,
        f"Produced by `{command}`; every table, row by row, is in `models/{EVALUATION}`.",
        "",
        "Union spectrum and region from the spectrum, pooled over the groups of each split:",
        "",
        *summary_table(metrics),
        "",
        *test_c_strata_table(metrics),
        "",
        *session_table(metrics),
        "",
        "Identity retrieval (the paper's Table 4):",
        "",
        *retrieval_table(metrics),
        END,
    ]
    return "\n".join(lines)


def _told_section(metrics: dict) -> list[str]:
    table = told_table(metrics)
    if not table:
        return []
    return [
        "## Told the overlap (`overlap`: the share of the smaller part inside the other, where a client knows it)",
        "The same Test C and Test B rows, the operator told each pair's true share (template areas), then that",
        "share plus Gaussian noise of 0.1 (clipped to 0 … 1), as a client's measurement might be; for an",
        "operator that reads it, told the boundary share too (template edges), exactly and plus noise of 0.06.",
        "",
        *table,
        "",
    ]


def update_card(models: Path, metrics: dict, command: str) -> None:
    """Replace the card's generated section (or append one) and write every table to ``EVALUATION.md``."""
    replace_block(models / CARD, BEGIN, END, render_summary(metrics, command))
    (models / EVALUATION).write_text(render(metrics, command))


def replace_block(path: Path, begin: str, end: str, block: str) -> None:
    """Put ``block`` (which starts with ``begin`` and ends with ``end``) where those markers are
    in the file, or append it: each generated section of the card has its own pair."""
    text = path.read_text() if path.exists() else ""
    if begin in text and end in text:
        text = text[: text.index(begin)] + block + text[text.index(end) + len(end) :]
    else:
        text = text.rstrip() + "\n\n" + block + "\n"
    path.write_text(text)
