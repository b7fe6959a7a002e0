"""The house's import rules, read from the source (docs/architecture.md): the service never imports
the training side, torch or anny; the training side takes from the service only through its entry
points; tests and benchmarks share helpers through ``harness`` and never import each other."""

import ast
import importlib
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
ENTRY_POINTS = {"app.contract", "app.samples", "app.geometry", "app.inference", "app.sessions", "app.retrieval"}
PACKAGES = sorted(name for name in ENTRY_POINTS if (ROOT / name.replace(".", "/")).is_dir())


def imported(folder: str) -> list[tuple[Path, str, tuple[str, ...]]]:
    """Every import in ``folder``'s Python files: (file, module, names taken from it)."""
    found = []
    for path in sorted((ROOT / folder).rglob("*.py")):
        for node in ast.walk(ast.parse(path.read_text(), str(path))):
            if isinstance(node, ast.Import):
                found += [(path, alias.name, ()) for alias in node.names]
            elif isinstance(node, ast.ImportFrom) and node.level == 0 and node.module:
                found.append((path, node.module, tuple(alias.name for alias in node.names)))
    return found


def top(module: str) -> str:
    return module.split(".")[0]


def test_the_service_never_imports_training_torch_or_anny() -> None:
    wrong = [(str(path), module) for path, module, _ in imported("app") if top(module) in {"training", "torch", "anny"}]
    assert wrong == []


def test_training_takes_from_the_service_only_through_its_entry_points() -> None:
    wrong = [
        (str(path), module)
        for path, module, _ in imported("training")
        if top(module) == "app" and module not in ENTRY_POINTS
    ]
    assert wrong == []


@pytest.mark.parametrize("package", PACKAGES)
def test_every_name_training_takes_is_a_public_name_that_resolves(package: str) -> None:
    exported = importlib.import_module(package)
    taken = {name for _, module, names in imported("training") if module == package for name in names}
    assert taken, f"training takes nothing from {package}: drop it from the entry points"
    assert taken <= set(exported.__all__)
    for name in exported.__all__:  # the table names real objects of real modules
        assert getattr(exported, name) is not None


def test_a_package_loads_a_module_when_one_of_its_names_is_first_asked_for() -> None:
    """A package's public names cost nothing until used: a solver worker loads what it solves with."""
    code = (
        "import sys, app.geometry as g; before = 'app.geometry.pipeline' in sys.modules; g.SpectrumOptions; "
        "print(int(before), int('app.geometry.pipeline' in sys.modules))"
    )
    printed = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True, cwd=ROOT)
    assert printed.stdout.split() == ["0", "1"]


@pytest.mark.parametrize(("folder", "other"), [("tests", "benchmarks"), ("benchmarks", "tests")])
def test_tests_and_benchmarks_do_not_import_each_other(folder: str, other: str) -> None:
    assert [(str(path), module) for path, module, _ in imported(folder) if top(module) == other] == []
