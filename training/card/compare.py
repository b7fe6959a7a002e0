"""Before/after tables of two evaluations (``metrics.json`` or ``spectral-unions-train score``
output) on the same data set: what a model change did to every table of the card.

The card shows every existing table before and after a model change; this writes them from the
two files instead of by hand, so that no cell is copied wrong and no row is left out.
"""

from training.card.tables import BASELINES, percent
from training.localizer.masks import SERVED_LOCALIZER


def _mre(row: dict, method: str = "operator") -> float:
    return row["union"][method]["mre"]


def _coverage(before: dict | None, after: dict) -> str:
    if "interval_coverage" not in after:
        return "—"
    old = percent(before["interval_coverage"]) if before and "interval_coverage" in before else "—"
    return f"{old} → {percent(after['interval_coverage'])}"


def rows_table(before: dict, after: dict) -> list[str]:
    """Every union row (Test A/B per group and variant), then the chains of three parts."""
    lines = [
        "| row | n | operator mae / mre before | after | Δ mre (points) | 90 % coverage before → after "
        "| disjoint_union mre | lookup mre |",
        "|---|---|---|---|---|---|---|---|",
    ]
    cases = [(key, before["rows"].get(key), row) for key, row in after["rows"].items()]
    cases.append(("chains (A∪B)∪C", before.get("chains"), after["chains"]))
    for key, old, new in cases:
        ours = new["union"]["operator"]
        was = f"{old['union']['operator']['mae']:.2f} / {percent(_mre(old))}" if old else "—"
        delta = f"{100 * (_mre(new) - _mre(old)):+.1f}" if old else "—"
        lines.append(
            f"| {key} | {new['rows']} | {was} | {ours['mae']:.2f} / {percent(ours['mre'])} | {delta} | "
            f"{_coverage(old, new)} | {percent(_mre(new, 'disjoint_union'))} | {percent(_mre(new, 'lookup'))} |"
        )
    return lines


def strata_table(before: dict, after: dict) -> list[str]:
    """Overlap strata of Test C and Test A with the baselines beside the operator."""
    lines = [
        "| stratum | n | operator mre before | after | "
        + " | ".join(BASELINES)
        + " | 90 % coverage before → after | above min after |",
        "|---" * (6 + len(BASELINES)) + "|",
    ]
    for key, new in after.get("strata", {}).items():
        old = before.get("strata", {}).get(key)
        baselines = " | ".join(percent(_mre(new, b)) for b in BASELINES)
        lines.append(
            f"| {key} | {new['rows']} | {percent(_mre(old)) if old else '—'} | {percent(_mre(new))} | {baselines} | "
            f"{_coverage(old, new)} | {percent(new['above_minimum'])} |"
        )
    return lines


def _baseline_cells(row: dict) -> str:
    return " | ".join(percent(_mre(row, b)) for b in ("elementwise_min", "disjoint_union", "lookup"))


def sessions_table(before: dict, after: dict) -> list[str]:
    """Test C by kind of session pair and its chains of consecutive views, then associativity."""
    lines = [
        "| Test C pair kind / chain | n | operator mre before | after | elementwise_min | disjoint_union | lookup "
        "| 90 % coverage |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for kind, new in after.get("test_c_kinds", {}).items():
        old = before.get("test_c_kinds", {}).get(kind)
        lines.append(
            f"| {kind} | {new['rows']} | {percent(_mre(old)) if old else '—'} | {percent(_mre(new))} | "
            f"{_baseline_cells(new)} | — |"
        )
    chains, old_chains = after.get("test_c_chains", {}), before.get("test_c_chains", {})
    for length, new in chains.items():
        if length == "associativity":
            continue
        old = old_chains.get(length)
        was = percent(_mre(old)) if old else "—"
        lines.append(
            f"| chain of {length} views | {new['rows']} | {was} | {percent(_mre(new))} | "
            f"{_baseline_cells(new)} | {_coverage(old, new)} |"
        )
    if "associativity" in chains:
        old = old_chains.get("associativity", {}).get("mean_relative_gap")
        gap = chains["associativity"]
        lines.append(
            f"| associativity gap (views 0, 1, 2) | {gap['rows']} | {percent(old) if old is not None else '—'} | "
            f"{percent(gap['mean_relative_gap'])} | — | — | — | — |"
        )
    return lines


def localization_table(before: dict, after: dict, localizer: str = SERVED_LOCALIZER) -> list[str]:
    """The service localizer's symmetric IoU on every row that has it."""
    lines = ["| localization IoU (service localizer) | before | after |", "|---|---|---|"]
    for key, new in after["rows"].items():
        if localizer not in new.get("localization", {}):
            continue
        old = before["rows"].get(key, {}).get("localization", {}).get(localizer)
        was = percent(old["iou"]) if old else "—"
        lines.append(f"| {key} | {was} | {percent(new['localization'][localizer]['iou'])} |")
    return lines


def retrieval_table(before: dict, after: dict) -> list[str]:
    lines = ["| retrieval | before top-1 / 5 / 10 | after |", "|---|---|---|"]

    def rates(row: dict | None) -> str:
        return " / ".join(f"{100 * row[f'top{t}']:.1f}" for t in (1, 5, 10)) + " %" if row else "—"

    for name, new in after.get("retrieval", {}).items():
        lines.append(f"| {name} | {rates(before.get('retrieval', {}).get(name))} | {rates(new)} |")
    return lines


def comparison(before: dict, after: dict) -> str:
    """Every table, before → after, as Markdown."""
    tables = [rows_table, strata_table, sessions_table, localization_table]
    if after.get("retrieval"):
        tables.append(retrieval_table)
    return "\n\n".join("\n".join(table(before, after)) for table in tables) + "\n"
