"""How far two part spectra tell whether one part lies inside the other: an upper bound on what
any union operator can gain on the nested and same-region strata.

    python benchmarks/nesting_ambiguity.py [--data data/standard] [--models models]

A pair whose smaller part lies (almost) inside the other has the larger part as its union, and
the elementwise minimum of the two spectra is then nearly exact. The operator only sees the
two spectra, so it can only be as right there as the spectra tell "nested" apart from "adds
something". This trains a classifier for exactly that question (an MLP on the pair's
scale-free log-spectra, smaller part first; labels from the template masks; training rows
only, a fixed 40 epochs) and reports, per overlap stratum of validation, Test A
and Test C: its AUC and how many pairs it calls nested, and the mean relative error of the
served operator, of the elementwise minimum, and of the operator replaced by the minimum
wherever the classifier says "nested" (p > 0.5): what a nesting gate as good as this
classifier would give.
"""

from collections.abc import Callable

import numpy as np
import torch

from training.benchmark_arguments import benchmark_parser
from training.learning.data import PairTable, SpectralData
from training.learning.evaluate import served_predictors, strata

NOTHING_ADDED = ("nested", "same_region")  # strata whose union is (one of) the parts
EPOCHS = 40


def pair_features(rows: PairTable) -> np.ndarray:
    """z of the smaller part (larger mean eigenvalue), z of the larger, and their difference."""
    a, b = rows.a.astype(np.float64), rows.b.astype(np.float64)
    swap = a.mean(1) < b.mean(1)
    small, large = np.where(swap[:, None], b, a), np.where(swap[:, None], a, b)
    scale = (small.mean(1, keepdims=True) + large.mean(1, keepdims=True)) / 2
    z_small, z_large = np.log(small.clip(0) / scale + 1e-3), np.log(large.clip(0) / scale + 1e-3)
    return np.concatenate([z_small, z_large, z_small - z_large], 1).astype(np.float32)


def area_under_curve(score: np.ndarray, positive: np.ndarray) -> float:
    """The probability that a positive pair scores above a negative one (ties count half)."""
    if positive.all() or not positive.any():
        return float("nan")
    ranks = np.argsort(np.argsort(score)) + 1.0
    return float(
        (ranks[positive].sum() - positive.sum() * (positive.sum() + 1) / 2) / (positive.sum() * (~positive).sum())
    )


def classifier(features: np.ndarray, labels: np.ndarray) -> Callable[[np.ndarray], np.ndarray]:
    """P(nested) of a pair's features: an MLP 60 → 256 → 256 → 1 on standardized features,
    trained by cross-entropy (seed 0)."""
    torch.manual_seed(0)
    x, y = torch.as_tensor(features), torch.as_tensor(labels, dtype=torch.float32)
    mean, std = x.mean(0), x.std(0) + 1e-6
    net = torch.nn.Sequential(
        torch.nn.Linear(x.shape[1], 256), torch.nn.GELU(), torch.nn.Linear(256, 256), torch.nn.GELU(),
        torch.nn.Linear(256, 1),
    )  # fmt: skip
    optimizer = torch.optim.Adam(net.parameters(), 1e-3, weight_decay=1e-5)
    for _ in range(EPOCHS):
        for batch in torch.randperm(len(x)).split(256):
            loss = torch.nn.functional.binary_cross_entropy_with_logits(net((x[batch] - mean) / std)[:, 0], y[batch])
            optimizer.zero_grad()
            loss.backward()
            optimizer.step()
    net.eval()
    return lambda f: torch.sigmoid(net((torch.as_tensor(f) - mean) / std)[:, 0]).detach().numpy()


def relative_error(predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """Per pair, the mean relative error of λ₂…λ_k (λ₁ of a closed union is 0)."""
    return (np.abs(predicted - truth)[:, 1:] / truth[:, 1:].clip(1e-9)).mean(1)


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    args = parser.parse_args()
    data = SpectralData(args.data)
    union, _ = served_predictors(args.models)
    splits = {}
    for split in ("train", "validation", "test_a", "test_c"):
        rows = data.pairs.rows(np.flatnonzero(data.pairs.split == split))
        labels = strata(data, rows)
        kept = np.flatnonzero(labels != "identical")  # one spectrum twice: the gate makes it exact
        splits[split] = (rows.rows(kept), labels[kept])
    train_rows, train_labels = splits["train"]
    nested = classifier(pair_features(train_rows), np.isin(train_labels, NOTHING_ADDED))
    columns = ("rows", "stratum", "variant", "n", "AUC (whole split)", "called nested", "operator", "minimum")
    print("| " + " | ".join(columns) + " | operator, minimum where called nested |")
    print("|---|---|---|---|---|---|---|---|---|")
    for split in ("validation", "test_a", "test_c"):
        rows, labels = splits[split]
        probability = nested(pair_features(rows))
        auc = area_under_curve(probability, np.isin(labels, NOTHING_ADDED))
        operator = union(rows.a, rows.b)[0]
        minimum = np.minimum(rows.a, rows.b)
        gated = np.where(probability[:, None] > 0.5, minimum, operator)
        errors = [relative_error(x, rows.union) for x in (operator, minimum, gated)]
        for stratum in ("same_region", "nested", "over_75", "25_to_75", "under_25", "all"):
            for variant in np.unique(rows.variant):
                chosen = (rows.variant == variant) & ((labels == stratum) | (stratum == "all"))
                if chosen.sum() < 5:
                    continue
                cells = " | ".join(f"{100 * e[chosen].mean():.1f} %" for e in errors)
                print(
                    f"| {split} | {stratum} | {variant} | {chosen.sum()} | {auc:.3f} "
                    f"| {100 * np.mean(probability[chosen] > 0.5):.0f} % | {cells} |"
                )


if __name__ == "__main__":
    main()
