"""The README's "What it reaches" table copies no figure by hand: every number in a row that
cites the model card is one the card (generated from the metrics files) or its evaluation
tables print, so a retrained model cannot leave the README saying what an earlier one did."""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
NUMBER = re.compile(r"(?<![\w.])\d+(?:\.\d+)?(?![\w.])")


def _rows_citing_the_card() -> list[list[str]]:
    text = (ROOT / "README.md").read_text()
    table = text[text.index("## What it reaches") :].split("\n## ")[0]
    rows = [
        [cell.strip() for cell in line.strip("|").split("|")] for line in table.splitlines() if line.startswith("| ")
    ]
    return [row for row in rows[1:] if "model card" in row[-1] or "EVALUATION.md" in row[-1]]


def _decimals(cell: str) -> set[str]:
    """The measured figures of a cell: numbers with a decimal point (counts, goals and names'
    digits are not measurements)."""
    return {number for number in NUMBER.findall(cell) if "." in number}


def test_the_readme_cites_the_card_for_most_of_its_figures():
    assert len(_rows_citing_the_card()) >= 8


def _printed(source: str) -> set[str]:
    """Every number the document a row cites prints."""
    name = "EVALUATION.md" if "EVALUATION.md" in source else "MODEL_CARD.md"
    return set(NUMBER.findall((ROOT / "models" / name).read_text()))


def test_every_figure_the_readme_takes_from_the_card_is_the_cards():
    missing = {
        row[0]: sorted(_decimals(row[1] + " " + row[2]) - _printed(row[-1]))
        for row in _rows_citing_the_card()
        if _decimals(row[1] + " " + row[2]) - _printed(row[-1])
    }
    assert not missing, f"README figures the card does not print: {missing}"
