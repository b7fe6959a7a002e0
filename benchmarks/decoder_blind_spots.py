"""A complete scan with blind spots, decoded: which blind spot costs what.

    python -m benchmarks.decoder_blind_spots [--data data/standard] [--models models] [--other DIR]

The benchmark's unknown people (the decoder's test identities), every complete posed body scanned
with one kind of blind spot at a time, each kind a fixed size: the soles (1.5 cm above the lowest
vertex, what a standing scan misses), the top of the head (4 cm), both, and three random 4 cm
spots (an armpit, the crotch, an occluded patch). Each scan's spectrum (σ = 0, one measured
upload) goes to the served decoder as ``/v1/reconstruct`` sends it, and the rebuilt body is
scored against the person's rest-pose body as the model card scores it; so does the same scan
uploaded with ``cap_holes=true`` (its holes capped: a closed surface's spectrum). ``--other`` scores a
second models directory on the same scans (before/after tables).
"""

from pathlib import Path

import numpy as np

from app.inference.models import SpectralModels
from benchmarks.arguments import benchmark_parser
from training.common.data import SpectralData
from training.reconstruction.blind_spots import (
    above_soles,
    away_from,
    blind_spot_masks,
    head_top,
    scans_of_shapes,
)
from training.reconstruction.evaluate import BLIND_SPOT_SEED, UNKNOWN_GROUPS, body_scores, identity_groups
from training.reconstruction.train import data_set_rest_bodies

SOLES, HEAD, SPOT = 0.015, 0.04, 0.04  # m
SPOTS = 3


def kind_masks(vertices: np.ndarray, count: int, rng: np.random.Generator) -> dict[str, list[np.ndarray]]:
    """``count`` masks of each kind of blind spot."""
    soles, head = above_soles(vertices, SOLES), away_from(vertices, head_top(vertices), HEAD)

    def spots() -> np.ndarray:
        centres = rng.choice(len(vertices), SPOTS, replace=False)
        return np.logical_and.reduce([away_from(vertices, c, SPOT) for c in centres])

    return {
        "soles": [soles] * count,
        "top of the head": [head] * count,
        "soles and head": [soles & head] * count,
        f"{SPOTS} random spots": [spots() for _ in range(count)],
        "the card's blind_spots row (its draws)": blind_spot_masks(vertices, count, BLIND_SPOT_SEED),
    }


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    parser.add_argument("--other", type=Path, help="a second models directory, scored on the same scans")
    args = parser.parse_args()
    data = SpectralData(args.data)
    shapes, complete = data.complete_spectra()
    shapes = shapes[np.isin(data.identity_of(shapes), np.flatnonzero(np.isin(identity_groups(data), UNKNOWN_GROUPS)))]
    rest = data_set_rest_bodies(data).astype(np.float64)
    directories = [args.models] + ([args.other] if args.other else [])
    decoders = [SpectralModels(directory) for directory in directories]
    area = data.vertex_area
    print(f"{len(shapes)} complete posed bodies of {len(np.unique(data.identity_of(shapes)))} unknown people")
    print(
        "| blind spot | body area unseen | "
        + " | ".join(f"{d} mean / p95 mm" for d in directories)
        + f" | {args.models}, cap_holes=true mean / p95 mm |"
    )
    print("|---|---|" + "---|" * (len(directories) + 1))
    for kind, masks in kind_masks(data.template.vertices, len(shapes), np.random.default_rng(0)).items():
        spectra, scanned = scans_of_shapes(data, shapes, masks, complete.shape[1])
        unseen = np.mean([1 - area[m].sum() / area.sum() for m in masks])
        truth = rest[data.identity_of(scanned)]
        capped, closed_up = scans_of_shapes(data, shapes, masks, complete.shape[1], cap_holes=True)
        rows = [(models, spectra, truth) for models in decoders] + [
            (decoders[0], capped, rest[data.identity_of(closed_up)])
        ]
        cells = []
        for models, queries, people in rows:
            bodies = np.stack([models.reconstruct(s, np.zeros_like(s)) for s in queries])
            score = body_scores(bodies, people, data.template.faces)
            cells.append(f"{score['vertex_mean_mm']:.1f} / {score['vertex_p95_mm']:.1f}")
        print(f"| {kind} | {100 * unseen:.2f} % | " + " | ".join(cells) + " |")


if __name__ == "__main__":
    main()
