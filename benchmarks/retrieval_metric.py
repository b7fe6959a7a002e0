"""Which distance finds a person from the predicted union of their partial scans: the ShapeDNA
Euclidean distance against metrics that know how the union errs.

    python benchmarks/retrieval_metric.py [--data data/standard] [--runs runs/standard] [--models models]

Identity lives in ~1 % differences of the spectrum, below the union's error, and that error is
not isotropic: it is correlated across eigenvalues (a scale slip moves them all), which a
Euclidean distance on log-eigenvalues reads as a different person. A Mahalanobis distance whose
covariance is the *within-person* scatter of (query, stored shape of the same person) differences
discounts exactly those directions. It is fitted on training identities only: the operator's
leave-one-body-out predicted unions of their full-coverage training pairs (every memory row of
the pair's own posed body hidden, as for a new person) against their complete bodies in the
other poses. It is a linear map of the features, so an index over transformed features (the
PostgreSQL cube) serves it unchanged.

Scored on the retrieval queries of the model card (full-coverage test pairs, every group and
variant, queried against every complete posed body but their own shape; the served ONNX
operator's unions and σ), and, for the complete shapes against each other, with the pose-only
covariance. Rows: Euclidean (today's ShapeDNA); σ-weighted (each log-eigenvalue difference over
the query's relative σ and the pose spread); Mahalanobis (pose only); Mahalanobis (union error
and pose). Prints a Markdown table.
"""

from pathlib import Path

import numpy as np
import torch

from app.retrieval.distance import features
from training.benchmark_arguments import benchmark_parser
from training.learning.data import SpectralData
from training.learning.evaluate import served_predictors
from training.learning.shapedna import feature_hits, full_coverage_pairs, stored_bodies
from training.learning.train_union import build_operator, memory_rows, predict
from training.learning.union_net import UnionConfig

SHRINK = 1e-3  # ridge on the covariance, relative to its mean variance: keeps the inverse tame


def trained_operator(data: SpectralData, checkpoint: Path):
    """The run's best weights in an operator whose memory holds the training pairs."""
    state = torch.load(checkpoint, map_location="cpu", weights_only=False)
    config = UnionConfig(**state["config"]["model"])
    model = build_operator(data.pairs.rows(memory_rows(data)), config)
    model.load_state_dict(state["best_weights"])
    return model.eval()


def whitening(differences: np.ndarray) -> np.ndarray:
    """L with Lᵀ L = (Σ + ridge)⁻¹ for the covariance Σ of zero-mean ``differences``: Euclidean
    distance after L is the Mahalanobis distance."""
    covariance = differences.T @ differences / len(differences)
    covariance += SHRINK * np.trace(covariance) / len(covariance) * np.eye(len(covariance))
    return np.linalg.cholesky(np.linalg.inv(covariance)).T


def same_person_differences(
    queries: np.ndarray, query_shapes: np.ndarray, stored: np.ndarray, identity: np.ndarray
) -> np.ndarray:
    """Feature differences of each query from every stored shape of its person but its own shape."""
    out = []
    for query, shape in zip(features(queries), query_shapes, strict=True):
        others = np.flatnonzero((identity == identity[shape]) & (np.arange(len(identity)) != shape))
        out.append(features(stored[others]) - query)
    return np.concatenate(out)


def main() -> None:
    parser = benchmark_parser(__doc__)
    parser.add_argument("--runs", type=Path, default=Path("runs/standard"))
    parser.add_argument("--models", type=Path, default=Path("models"))
    args = parser.parse_args()
    data = SpectralData(args.data)
    stored, identity = stored_bodies(data, args.models)
    train, test = full_coverage_pairs(data.pairs)
    trained_people = np.unique(identity[train.shape_a])
    assert not np.isin(identity[test.shape_a], trained_people).all(), "some test queries are of unseen people"

    # Fitted on training identities only.
    operator = trained_operator(data, args.runs / "union.pt")
    memory_bodies = data.pairs.shape_a[memory_rows(data)]
    train_unions = predict(operator, train.a, train.b, (memory_bodies, train.shape_a))[0]
    union_metric = whitening(same_person_differences(train_unions, train.shape_a, stored, identity))
    trained_shapes = np.flatnonzero(np.isin(identity, trained_people))
    pose_differences = same_person_differences(stored[trained_shapes], trained_shapes, stored, identity)
    pose_metric, pose_spread = whitening(pose_differences), np.sqrt(np.mean(pose_differences**2, 0))

    union, _ = served_predictors(args.models)
    queries, sigma = union(test.a, test.b)
    relative_sigma = sigma[:, 1:] / np.clip(queries[:, 1:], 1e-9, None)
    stored_features, query_features = features(stored), features(queries)
    every_shape = np.arange(len(stored))
    unseen = ~np.isin(identity[test.shape_a], trained_people)
    table = {
        ("predicted unions", "Euclidean (ShapeDNA, served)"): feature_hits(
            query_features, test.shape_a, stored_features, identity
        ),
        ("predicted unions", "σ-weighted"): feature_hits(
            query_features, test.shape_a, stored_features, identity, 1 / np.sqrt(relative_sigma**2 + pose_spread**2)
        ),
        ("predicted unions", "Mahalanobis, pose"): feature_hits(
            query_features @ pose_metric.T, test.shape_a, stored_features @ pose_metric.T, identity
        ),
        ("predicted unions", "Mahalanobis, union error + pose"): feature_hits(
            query_features @ union_metric.T, test.shape_a, stored_features @ union_metric.T, identity
        ),
        ("complete shapes", "Euclidean (ShapeDNA, served)"): feature_hits(
            stored_features, every_shape, stored_features, identity
        ),
        ("complete shapes", "Mahalanobis, pose"): feature_hits(
            stored_features @ pose_metric.T, every_shape, stored_features @ pose_metric.T, identity
        ),
    }
    print(f"{len(test)} union queries ({unseen.sum()} of people never trained on), {len(stored)} stored shapes")
    print("| queries | distance | top-1 | top-5 | top-10 | top-1, people never trained on |")
    print("|---|---|---|---|---|---|")
    for (queries_name, name), hit in table.items():
        new_people = unseen if queries_name == "predicted unions" else ~np.isin(identity, trained_people)
        cells = " | ".join(f"{100 * rate:.1f} %" for rate in hit.mean(0))
        print(f"| {queries_name} | {name} | {cells} | {100 * hit[new_people, 0].mean():.1f} % |")


if __name__ == "__main__":
    main()
