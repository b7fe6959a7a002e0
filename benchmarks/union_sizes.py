"""What the splits' two-part unions look like: why the disjoint union is as good as the operator on
Test B and far worse on the training rows of the same scenario.

    python benchmarks/union_sizes.py [--data data/standard] [--models models]

Per split, its pairs of the "partial" scenario (two overlapping parts whose union falls short of
the body; Test B's are its held-out union types, each split into two parts), mesh parts: the
medians of the union's share of the body, the smaller part's area over the larger's, and the
overlap's share of the smaller part and of the union (template masks, lumped vertex areas); and
the mean relative error (λ₂…λ_k) of the disjoint union and of the served operator (not for the
training rows, which the operator's memory holds; validation's are through the served graph,
whose memory holds other pairs of the same bodies).
"""

import numpy as np

from training.benchmark_arguments import benchmark_parser
from training.data.pairs import PARTIAL_UNION
from training.data.spectra import MESH
from training.learning.baselines import disjoint_union
from training.learning.data import SpectralData
from training.learning.evaluate import served_predictors


def relative_error(predicted: np.ndarray, truth: np.ndarray) -> float:
    """The mean relative error of λ₂…λ_k over the rows."""
    return float((np.abs(predicted - truth)[:, 1:] / truth[:, 1:].clip(1e-9)).mean())


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    args = parser.parse_args()
    data = SpectralData(args.data)
    union = served_predictors(args.models)[0]
    weights = data.vertex_area
    print("| split | pairs | union / body | smaller / larger part | overlap / smaller | overlap / union "
          "| disjoint union | operator |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|")
    pairs = data.pairs
    for split in ("train", "validation", "test_a", "test_b"):
        rows = pairs.rows(
            np.flatnonzero((pairs.split == split) & (pairs.scenario == PARTIAL_UNION) & (pairs.variant == MESH))
        )
        a, b, joined = (data.masks(m) for m in (rows.mask_a, rows.mask_b, rows.mask_union))
        area_a, area_b, area_union, shared = a @ weights, b @ weights, joined @ weights, (a & b) @ weights
        smaller = np.minimum(area_a, area_b)
        shares = (
            area_union / weights.sum(),
            smaller / np.maximum(area_a, area_b),
            shared / smaller,
            shared / area_union,
        )
        disjoint = f"{100 * relative_error(disjoint_union(rows.a, rows.b), rows.union):.1f} %"
        operator = "—" if split == "train" else f"{100 * relative_error(union(rows.a, rows.b)[0], rows.union):.1f} %"
        cells = " | ".join(f"{np.median(s):.2f}" for s in shares) + f" | {disjoint} | {operator}"
        print(f"| {split} | {len(rows)} | {cells} |")


if __name__ == "__main__":
    main()
