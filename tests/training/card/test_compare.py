"""Before/after tables (training.card.compare) on the committed metrics."""

import copy
import json
from pathlib import Path

from training.card.compare import comparison

METRICS = Path(__file__).resolve().parents[3] / "models" / "metrics.json"


def test_every_row_and_stratum_is_shown_with_its_change():
    after = json.loads(METRICS.read_text())
    before = copy.deepcopy(after)
    row = next(iter(after["rows"]))
    before["rows"][row]["union"]["operator"]["mre"] += 0.012  # the new model is 1.2 points better there
    del before["strata"][next(iter(after["strata"]))]  # a stratum the earlier evaluation did not have
    rows_table, strata_table, *_ = comparison(before, after).split("\n\n")

    def keyed(table: str) -> dict[str, str]:
        return {line.split(" | ")[0].strip("| "): line for line in table.splitlines()[2:]}

    lines, strata = keyed(rows_table), keyed(strata_table)
    assert set(after["rows"]) <= set(lines) and set(after["strata"]) == set(strata)
    assert " | -1.2 | " in lines[row]
    assert all(" | +0.0 | " in lines[key] or " | -0.0 | " in lines[key] for key in after["rows"] if key != row)
    new_stratum = strata[next(iter(after["strata"]))]
    assert new_stratum.split(" | ")[2] == "—"  # no before figure: a dash, never a made-up one
