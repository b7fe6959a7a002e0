"""The command line every benchmark over a built data set shares (``benchmarks/*.py``): one
definition of where the data set and the served models are by default."""

import argparse
from pathlib import Path

DEFAULT_DATA = Path("data/standard")  # what ``make dataset`` builds
DEFAULT_MODELS = Path("models")  # what the service serves


def benchmark_parser(doc: str, *, models: bool = False) -> argparse.ArgumentParser:
    """A parser described by the first line of the benchmark's docstring, with ``--data`` and,
    for benchmarks of the served graphs, ``--models``."""
    parser = argparse.ArgumentParser(description=doc.splitlines()[0])
    parser.add_argument("--data", type=Path, default=DEFAULT_DATA)
    if models:
        parser.add_argument("--models", type=Path, default=DEFAULT_MODELS)
    return parser
