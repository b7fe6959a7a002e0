"""Print the laws of union measured on a models folder (default: the committed ``models/``).

    python benchmarks/bench_union_laws.py [MODELS_DIR]

Mean and worst relative error per law over fresh parts of the template body
(:mod:`training.union.laws`); the tolerances of ``tests/inference/test_union_laws.py`` and the
model card's law table come from here.
"""

import sys
from pathlib import Path

import numpy as np

from app.inference.models import SpectralModels
from training.data.regions import RegionSampler
from training.data.template import Template
from training.union.laws import law_parts, measure_laws

MODELS = Path(__file__).resolve().parents[1] / "models"


def main() -> None:
    directory = Path(sys.argv[1]) if len(sys.argv) > 1 else MODELS
    parts = law_parts(RegionSampler(Template.load(MODELS)))
    for law, values in measure_laws(SpectralModels(directory), parts).items():
        print(f"{law:22s} n={len(values):3d} mean={np.mean(values):.5f} worst={np.max(values):.5f}")


if __name__ == "__main__":
    main()
