"""Why the untold union's 90 % interval cannot hold 90 % in every overlap stratum: what σ would
have to be scaled by in each, and how wide the overlap's own ambiguity is.

    python benchmarks/overlap_ambiguity.py [--data data/standard] [--models models]

The served union graph reads the overlap (the share of the smaller part inside the other). Asked
untold, it answers for the overlap its training pairs typically had; asked told 0 ("nothing
shared") and told 1 ("one inside the other"), it answers for the two ends of the range. Per
overlap stratum of Test A (known union types), Test C (scanning sessions) and per group of
Test B (unions unlike any in training), mesh and re-meshed parts: the untold union's mean
relative error and its 90 % coverage; the two told ends' errors; how many true eigenvalues lie
between the two ends; and the factor the stratum would need, at its 90th percentile, on the
served σ (err / 1.645σ) and on the ends' distance from the untold answer (err / 1.645·range,
the range being the farther end's distance at each eigenvalue, over the eigenvalues that have
one): a σ term that is stable across strata needs about the same factor in each.
"""

import numpy as np

from app.contract import INTERVAL_Z, UNKNOWN_OVERLAP
from training.benchmark_arguments import benchmark_parser
from training.data.spectra import MESH, REMESHED
from training.learning.data import PairTable, SpectralData
from training.learning.evaluate import served_told_predictor, strata
from training.learning.spectral_errors import spectral_errors

ENDS = (0.0, 1.0)  # told "nothing shared", told "one inside the other"
RANGELESS = 1e-3  # ends closer than this share of the answer: no range to scale (reported when most are)


def stratum_row(label: str, rows: PairTable, answers: dict[float, tuple[np.ndarray, np.ndarray]]) -> str:
    """One table row: errors, coverage, share in range and the factors needed, for these pairs."""
    mean, sigma = answers[UNKNOWN_OVERLAP]
    truth = rows.union
    apart, inside = answers[ENDS[0]][0], answers[ENDS[1]][0]
    farther = np.maximum(np.abs(apart - mean), np.abs(inside - mean))
    error = np.abs(mean - truth)
    between = (truth >= np.minimum(apart, inside)) & (truth <= np.maximum(apart, inside))
    sigma_factor = np.quantile(error / (INTERVAL_Z * np.maximum(sigma, 1e-12)), 0.9)
    ranged = farther > RANGELESS * np.abs(mean)  # a part with itself (or its re-scan) has no range
    range_factor = np.quantile(error[ranged] / (INTERVAL_Z * farther[ranged]), 0.9) if ranged.mean() > 0.5 else None

    def mre(prediction: np.ndarray) -> str:
        return f"{100 * spectral_errors(prediction, truth)['mre']:.1f} %"

    cells = [
        label,
        str(len(rows)),
        mre(mean),
        f"{100 * np.mean(error <= INTERVAL_Z * sigma):.1f} %",
        mre(apart),
        mre(inside),
        f"{100 * between.mean():.1f} %",
        f"{sigma_factor:.2f}",
        "— (no range)" if range_factor is None else f"{range_factor:.2f}",
    ]
    return "| " + " | ".join(cells) + " |"


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    args = parser.parse_args()
    data = SpectralData(args.data)
    told = served_told_predictor(args.models)
    if told is None:
        raise SystemExit(f"{args.models}: the union graph does not read the overlap")
    pairs = data.pairs
    print("| split / stratum or group / variant | n | untold mre | 90 % coverage | told 0 mre | told 1 mre "
          "| truth between the ends | σ factor needed | range factor needed |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    for split in ("test_a", "test_c", "test_b"):
        chosen = pairs.rows(np.flatnonzero((pairs.split == split) & np.isin(pairs.variant, [MESH, REMESHED])))
        labels = chosen.group if split == "test_b" else strata(data, chosen)
        answers = {share: told(chosen.a, chosen.b, np.full(len(chosen), share)) for share in (UNKNOWN_OVERLAP, *ENDS)}
        for label in np.unique(labels):
            for variant in (MESH, REMESHED):
                selection = np.flatnonzero((labels == label) & (chosen.variant == variant))
                if len(selection):
                    picked = {share: (m[selection], s[selection]) for share, (m, s) in answers.items()}
                    print(stratum_row(f"{split}/{label}/{variant}", chosen.rows(selection), picked))


if __name__ == "__main__":
    main()
