"""The two answers the union operator blends, each alone and blended, per kind of pair.

    python benchmarks/blend_answers.py [--data data/standard] [--runs runs/standard]

Outside training the operator's decrease from min(λ(A), λ(B)) is a per-pair blend of the
network's decrease and the median of what its 4 nearest training pairs' parts added
(``UnionOperator.blended``; the weight fitted on validation pairs and training chains by
``train_union.fit_blend``). This prints the mean relative error of the union with the network's
decrease alone (weight 0), the neighbours' median alone (weight 1) and the fitted blend, with
the blend's mean weight, on validation (leave-one-body-out, as fitted), the Test C pair kinds,
the Test B groups and the Test A kinds, mesh and re-meshed parts: where each answer is the
better one, which is why the operator blends them. The numbers the model card quotes for
"the neighbours' median alone" come from here.
"""

from pathlib import Path

import numpy as np
import torch

from training.benchmark_arguments import benchmark_parser
from training.data.spectra import MESH, REMESHED
from training.learning.data import SpectralData
from training.learning.spectral_errors import spectral_errors
from training.learning.train_union import load_operator, memory_rows, predict, same_body
from training.learning.union_net import UNFITTED_BLEND, UnionOperator

NEIGHBOURS_ALONE = (30.0, 0.0, 0.0, 0.0, 0.0)  # weight 1 − 1e-13 for every pair


@torch.no_grad()
def blend_weight(model: UnionOperator, a: np.ndarray, b: np.ndarray, bodies) -> float:
    """The fitted blend's mean weight over these pairs."""
    hidden = None if bodies is None else same_body(torch.as_tensor(bodies[0]), torch.as_tensor(bodies[1]))
    parts = model.proposal(torch.as_tensor(a), torch.as_tensor(b), hidden)
    _, features = model.blend_terms(parts)
    return float(torch.sigmoid(features @ model.blend_weights).mean())


def answers(model: UnionOperator, fitted: np.ndarray, a: np.ndarray, b: np.ndarray, union: np.ndarray, bodies) -> str:
    """One table row's cells: mre of the network alone, the neighbours alone, the blend; its weight."""
    cells = []
    for weights in (UNFITTED_BLEND, NEIGHBOURS_ALONE, fitted):
        model.set_blend_weights(weights)
        cells.append(f"{100 * spectral_errors(predict(model, a, b, bodies)[0], union)['mre']:.1f} %")
    return " | ".join(cells) + f" | {blend_weight(model, a, b, bodies):.2f}"


def main() -> None:
    parser = benchmark_parser(__doc__)
    parser.add_argument("--runs", type=Path, default=Path("runs/standard"))
    args = parser.parse_args()
    data = SpectralData(args.data)
    model = load_operator(data, args.runs / "union.pt")  # its blend fitted
    fitted = model.blend_weights.numpy().copy()
    pairs = data.pairs
    memory_bodies = pairs.shape_a[memory_rows(data)]
    print("| pairs | n | network alone | neighbours' median alone | blend (served) | mean weight |")
    print("|---|---|---|---|---|---|")
    validation = np.flatnonzero(pairs.split == "validation")
    rows = pairs.rows(validation)
    cells = answers(model, fitted, rows.a, rows.b, rows.union, (memory_bodies, rows.shape_a))
    print(f"| validation (leave-one-body-out) | {len(validation)} | {cells} |")
    for split, label in (("test_c", pairs.scenario), ("test_b", pairs.group), ("test_a", pairs.scenario)):
        for kind in np.unique(label[pairs.split == split]):
            for variant in (MESH, REMESHED):
                chosen = np.flatnonzero((pairs.split == split) & (label == kind) & (pairs.variant == variant))
                if len(chosen):
                    rows = pairs.rows(chosen)
                    cells = answers(model, fitted, rows.a, rows.b, rows.union, None)
                    print(f"| {split}/{kind}/{variant} | {len(chosen)} | {cells} |")


if __name__ == "__main__":
    main()
