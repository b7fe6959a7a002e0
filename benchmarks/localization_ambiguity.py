"""How far a part's spectrum tells where on the body the part is: random regions against the
views a depth camera sees, on the training rows themselves and on held-out ones.

    python benchmarks/localization_ambiguity.py [--data data/standard] [--models models]

The localizer is scored on Test B and Test C unions; this separates what it failed to learn from
what twenty eigenvalues do not say. For each kind of part (the benchmark's random regions, and
camera views of scanning sessions) and each split it localizes *true* part spectra (no union
error), and compares with two references that need no learning: the mask of the training part
whose spectrum is nearest (log-eigenvalues, Euclidean; another body's, since the rows scored
are held out or, for the training split, leave-one-body-out), and the mask of a random training
part of the same kind (chance). Scores: symmetric area IoU and the per-part coverage error
(mean absolute difference of each body part's covered share, in points), as in the card; and
IoU when a region may also be confused with its front/back reflection (the template reflected
through its coronal plane, nearest vertex), a second symmetry spectra might not tell.
"""

import numpy as np
from scipy.spatial import cKDTree
from scipy.spatial.distance import cdist

from app.contract import MASK_THRESHOLD
from app.inference.template import localized_region
from training.benchmark_arguments import benchmark_parser
from training.data.overlaps import CAMERA
from training.data.pairs import FULL_COVERAGE, PARTIAL_UNION
from training.data.spectra import MESH
from training.learning.data import PairTable, SpectralData
from training.learning.evaluate import served_predictors
from training.learning.masks import MaskScores, symmetric_scores

KINDS = {"random regions": (FULL_COVERAGE, PARTIAL_UNION), "camera views": CAMERA}
HELD_OUT = {"random regions": "test_a", "camera views": "test_c"}
ROWS = 600  # per split and kind: enough for a mean to ±2 points


def front_back(vertices: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """Vertex → nearest vertex of the template reflected front to back: the axis that is neither
    its height (largest extent) nor its left/right (along which a vertex and its mirror differ)."""
    height = int(np.argmax(np.ptp(vertices, axis=0)))
    side = int(np.argmax(np.abs(vertices - vertices[mirror]).mean(0)))
    axis = 3 - height - side
    reflected = vertices.copy()
    reflected[:, axis] = 2 * vertices[:, axis].mean() - reflected[:, axis]
    return cKDTree(vertices).query(reflected)[1]


def log_features(spectra: np.ndarray) -> np.ndarray:
    return np.log(np.clip(spectra, 1e-9, None))


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    args = parser.parse_args()
    data = SpectralData(args.data)
    region = served_predictors(args.models)[1]["all"]
    template, areas, pairs = data.template, data.vertex_area, data.pairs
    reflection = front_back(template.vertices, template.mirror)

    def scores(predicted_masks: np.ndarray, rows: PairTable) -> tuple[MaskScores, np.ndarray]:
        truth = data.masks(rows.mask_a)
        direct = symmetric_scores(predicted_masks, truth, areas, template.mirror, template.labels)
        flipped = symmetric_scores(predicted_masks, truth[:, reflection], areas, template.mirror, template.labels)
        return direct, np.maximum(direct.iou, flipped.iou)

    print("| part kind | split | n | method | IoU | IoU, front/back forgiven | part coverage error |")
    print("|---|---|---|---|---|---|---|")
    rng = np.random.default_rng(0)
    for kind, scenarios in KINDS.items():
        of_kind = (pairs.variant == MESH) & np.isin(pairs.scenario, scenarios)
        train = pairs.rows(np.flatnonzero(of_kind & (pairs.split == "train")))
        train_features = log_features(train.a)
        for split in ("train", "validation", HELD_OUT[kind]):
            rows = pairs.rows(np.flatnonzero(of_kind & (pairs.split == split))[:ROWS])
            # Nearest training part of another body (leave-one-body-out, as for held-out rows).
            distance = cdist(log_features(rows.a), train_features)
            distance[rows.shape_a[:, None] == train.shape_a[None]] = np.inf
            methods = {
                "served localizer, p ≥ 0.5": region(rows.a) >= MASK_THRESHOLD,
                "as /v1/localize answers (expected area)": localized_region(region(rows.a), [], areas, template.mirror),
                "nearest training spectrum's mask": data.masks(train.mask_a[np.argmin(distance, 1)]),
                "random training part (chance)": data.masks(train.mask_a[rng.integers(len(train), size=len(rows))]),
            }
            for name, masks in methods.items():
                direct, forgiven = scores(masks, rows)
                print(
                    f"| {kind} | {split} | {len(rows)} | {name} | {100 * direct.iou.mean():.1f} % "
                    f"| {100 * forgiven.mean():.1f} % | {100 * direct.coverage_error.mean():.1f} pt |"
                )


if __name__ == "__main__":
    main()
