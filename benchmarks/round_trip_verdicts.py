"""What the round trip's verdicts are read against for unions the operator predicts, by how much of the body they cover.

    python benchmarks/round_trip_verdicts.py [--data data/standard] [--models models] [--rows 200]

``/v1/reconstruct`` judges the rebuilt body by the gap between its own spectrum and the union's
(``app.api.rebuilt.round_trip``): closed, open (an open surface come back as scans with blind
spots do) or unseen (part of the body is not in the union: not to be trusted). A measured scan
with blind spots comes back 11–45 % away (the model card's ``blind_spots`` row); this benchmark
measures the unions the served operator predicts (σ > 0): Test A pairs covering the body, Test A
partial unions binned by the share of the body their union covers (template areas), and Test B's
partial unions; for each, the gap's percentiles and the verdict the service gives, beside the
verdict a measured scan's thresholds would give (σ = 0: the rule for every open union before
2026-12-04).
"""

from collections import Counter

import numpy as np

from app.api.rebuilt import round_trip
from app.inference.body import spectrum_gap
from app.inference.models import SpectralModels, UnionEstimate
from training.benchmark_arguments import benchmark_parser
from training.data.pairs import FULL_COVERAGE, PARTIAL_UNION
from training.data.spectra import MESH
from training.learning.data import SpectralData
from training.learning.evaluate import served_predictors
from training.reconstruction.evaluate import rebuilt_spectra

COVERAGE_BINS = (0.0, 0.5, 0.7, 0.8, 0.9, 1.01)
VERDICTS = ("closed", "open", "unseen")


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    parser.add_argument("--rows", type=int, default=200, help="pairs per set")
    args = parser.parse_args()
    data = SpectralData(args.data)
    models = SpectralModels(args.models)
    union = served_predictors(args.models)[0]
    pairs = data.pairs
    print("| unions | union covers | n | gap p5 / p50 / p95 | closed / open / unseen | judged as a measured scan |")
    print("|---|---|---|---|---|---|")
    for name, scenario, split in (
        ("Test A, two parts covering the body", FULL_COVERAGE, "test_a"),
        ("Test A partial unions", PARTIAL_UNION, "test_a"),
        ("Test B partial unions", PARTIAL_UNION, "test_b"),
    ):
        selection = (pairs.scenario == scenario) & (pairs.split == split) & (pairs.variant == MESH)
        rows = pairs.rows(np.flatnonzero(selection)[: args.rows])
        spectra, sigma = (x.astype(np.float64) for x in union(rows.a, rows.b))
        rebuilt = rebuilt_spectra(models, spectra, sigma)
        gaps = np.array([spectrum_gap(b, s) for b, s in zip(rebuilt, spectra, strict=True)])
        verdicts = np.array([round_trip(g, UnionEstimate(s, z)) for g, s, z in zip(gaps, spectra, sigma, strict=True)])
        as_measured = np.array(
            [round_trip(g, UnionEstimate(s, np.zeros_like(s))) for g, s in zip(gaps, spectra, strict=True)]
        )
        covered = np.ones(len(rows)) if scenario == FULL_COVERAGE else data.coverage(rows.mask_union)
        for low, high in zip(COVERAGE_BINS, COVERAGE_BINS[1:], strict=False):
            inside = (covered >= low) & (covered < high)
            if not inside.any():
                continue
            shares, measured = (
                " / ".join(f"{100 * Counter(judged[inside])[v] / inside.sum():.0f}" for v in VERDICTS)
                for judged in (verdicts, as_measured)
            )
            p05, p50, p95 = (100 * np.percentile(gaps[inside], q) for q in (5, 50, 95))
            print(
                f"| {name} | {100 * low:.0f}–{min(100 * high, 100):.0f} % | {inside.sum()} "
                f"| {p05:.0f} / {p50:.0f} / {p95:.0f} % | {shares} % | {measured} % |"
            )


if __name__ == "__main__":
    main()
