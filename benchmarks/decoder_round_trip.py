"""What the decoder's round trip can reach: the true body's own gap, and a body fitted to the spectrum.

    python benchmarks/decoder_round_trip.py [--data data/standard] [--models models] [--fit-rows 12]

Issue 22 asks the rebuilt body's spectrum to come back within 2 % of the spectrum it was decoded
from. Two references say what that figure can mean, on the model card's query sets (a) the
complete posed bodies of the benchmark's unknown people and (b) the served operator's unions of
two parts covering such a body:

- **the true body's gap**: the person's own rest-pose body, solved by the service's engine,
  against the query spectrum. A perfect decoder returns that body, so its round trip is this
  gap, not 0: pose moves a spectrum (~1.7 %, the card's noise floor) and a union is off by the
  operator's error.
- **a body fitted to the spectrum**: the decoded body refined at test time in the decoder's own
  shape basis until its spectrum meets the query's (:mod:`training.reconstruction.spectral_fit`),
  then measured as the card measures (the engine's intrinsic-Delaunay spectrum; rest pose after
  rigid alignment). ``--fit-rows`` rows per set (~12 s each on one core).

Prints two Markdown tables: every row of each set (decoder and true body), and the fitted rows
before and after the fit.
"""

import time

import numpy as np

from app.contract import RECONSTRUCTION_FILE
from app.inference.body import spectrum_gap
from app.inference.models import SpectralModels
from training.benchmark_arguments import benchmark_parser
from training.learning.data import SpectralData
from training.learning.evaluate import served_predictors
from training.reconstruction.evaluate import body_scores, closed_spectra, closed_spectrum, query_sets
from training.reconstruction.export import decoder_basis
from training.reconstruction.spectral_fit import CotangentSpectrum, fitted
from training.reconstruction.train import data_set_rest_bodies


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    parser.add_argument("--fit-rows", type=int, default=12)
    args = parser.parse_args()
    data = SpectralData(args.data)
    faces, rest = data.template.faces, data_set_rest_bodies(data).astype(np.float64)
    models = SpectralModels(args.models)
    basis, spectrum = decoder_basis(args.models / RECONSTRUCTION_FILE), CotangentSpectrum(faces, models.k)
    every = query_sets(data, served_predictors(args.models)[0])
    sets = {"true spectrum": every["true_spectrum"], "two-part union": every["two_part_union"]}
    people = np.unique(np.concatenate([identity for _, _, identity in sets.values()]))
    true_spectra = {p: closed_spectrum(rest[p], faces, models.k) for p in people}
    rng = np.random.default_rng(0)
    whole, fits = [], []
    for name, (spectra, sigma, identity) in sets.items():
        decoded = np.stack([models.reconstruct(s, z) for s, z in zip(spectra, sigma, strict=True)])
        ours = [spectrum_gap(b, s) for b, s in zip(closed_spectra(decoded, faces, models.k), spectra, strict=True)]
        truth = [spectrum_gap(true_spectra[p], s) for p, s in zip(identity, spectra, strict=True)]
        whole.append((name, len(spectra), ours, truth))
        for row in rng.choice(len(spectra), min(args.fit_rows, len(spectra)), replace=False):
            started = time.perf_counter()
            body = fitted(spectra[row], decoded[row], basis, spectrum)
            seconds = time.perf_counter() - started
            after = spectrum_gap(closed_spectrum(body, faces, models.k), spectra[row])
            person = rest[identity[row]][None]
            before_mm = body_scores(decoded[row][None], person, faces)["vertex_mean_mm"]
            after_mm = body_scores(body[None], person, faces)["vertex_mean_mm"]
            fits.append((name, ours[row], after, before_mm, after_mm, seconds))
    print(
        "| queries | n | decoder's round trip: mean / p95 | the true body's gap: mean / p95 | true body's gap > 2 % |"
    )
    print("|---|---|---|---|---|")
    for name, n, ours, truth in whole:
        print(
            f"| {name} | {n} | {100 * np.mean(ours):.1f} / {100 * np.percentile(ours, 95):.1f} % "
            f"| {100 * np.mean(truth):.1f} / {100 * np.percentile(truth, 95):.1f} % "
            f"| {100 * np.mean(np.array(truth) > 0.02):.0f} % |"
        )
    print()
    print("| queries | rows fitted | round trip: decoded → fitted | vertex mean mm: decoded → fitted | s per fit |")
    print("|---|---|---|---|---|")
    for name in sets:
        rows = np.array([fit[1:] for fit in fits if fit[0] == name])
        print(
            f"| {name} | {len(rows)} | {100 * rows[:, 0].mean():.2f} → {100 * rows[:, 1].mean():.2f} % "
            f"| {rows[:, 2].mean():.1f} → {rows[:, 3].mean():.1f} | {np.median(rows[:, 4]):.1f} |"
        )


if __name__ == "__main__":
    main()
