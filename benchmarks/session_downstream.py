"""What a scanning session's chained union gives downstream, and what limits it: the union or the coverage.

    python -m benchmarks.session_downstream [--data data/standard] [--models models]

Test C's chains of five consecutive camera views (unseen identities), read by the served
localizer (``/v1/localize``'s) and the served shape decoder (``/v1/reconstruct``'s) from three
spectra: the served operator's chained union untold (the model card's ``session_chain`` rows),
the chain told each step's true overlap (and boundary share, for models that read it), and the
true spectrum of the five views' union itself (σ 0). Localization: symmetric area IoU and
per-part coverage error against the union's true region, as the card scores them, the region as
``/v1/localize`` answers it (expected-area regions, the chained union's holding each view's
own; the true union's spectrum alone stands for one merged upload); decoding: vertex error against the person's
rest-pose body after rigid alignment; identity: the person among the service's seed database of
complete shapes (``models/shapes.npz``), ranked as ``/v1/retrieve`` ranks (an open surface
through the closed spectrum of the body rebuilt from it), the session's own posed body left
out, top-1/5/10 as the card's retrieval table counts them. Where the true union does no better,
what limits the row is not the union operator's error.
"""

import numpy as np

from app.inference.body import open_surface
from app.inference.models import SpectralModels, chained_sigma
from app.inference.template import localized_region
from benchmarks.arguments import benchmark_parser
from training.common.data import SpectralData
from training.localizer.masks import SERVED_LOCALIZER, symmetric_scores
from training.reconstruction.evaluate import body_scores, closed_spectra
from training.reconstruction.train import data_set_rest_bodies
from training.union.predictors import served_predictors, served_told_predictor
from training.union.shapedna import hit_rates, stored_bodies

TRUE_UNION = "the true union's spectrum"  # one operand: the five views uploaded merged


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    args = parser.parse_args()
    data = SpectralData(args.data)
    models = SpectralModels(args.models)
    untold, localizers = served_predictors(args.models)
    told = served_told_predictor(args.models)
    if told is None:
        raise SystemExit(f"{args.models} has a union operator that does not read the overlap")
    chains = data.chains
    truth = data_set_rest_bodies(data).astype(np.float64)[data.identity_of(chains.shape)]
    views = chains.views
    shares = data.chain_shares()
    chained = [
        ("operator untold", lambda a, b, step: untold(a, b)),
        ("operator told the true overlaps", lambda a, b, step: told(a, b, shares[:, step - 1])),
    ]
    if told.reads_boundary:
        boundaries = data.chain_boundaries()
        chained.append(
            (
                "operator told the true overlaps and boundary shares",
                lambda a, b, step: told(a, b, shares[:, step - 1], boundaries[:, step - 1]),
            )
        )
    answers = {}
    for name, union in chained:
        current, sigma = views[:, 0], np.zeros_like(views[:, 0])
        for step in range(1, views.shape[1]):
            step_union, step_sigma = union(current, views[:, step], step)
            sigma = chained_sigma(current, sigma, step_union, step_sigma)
            current = step_union
        answers[name] = (current, sigma)
    final = chains.unions[:, -1].astype(np.float64)
    answers[TRUE_UNION] = (final, np.zeros_like(final))
    covered = data.masks(chains.union_masks[:, -1]) @ models.vertex_area / models.vertex_area.sum()
    print(f"{len(final)} sessions; their union covers {np.median(covered):.2f} of the body (median)")
    region = localizers[SERVED_LOCALIZER]
    template = data.template
    true_region = data.masks(chains.union_masks[:, -1])
    stored, stored_identity = stored_bodies(data, args.models)
    person = data.identity_of(chains.shape)
    print(
        "| from | IoU | coverage error (points) | vertex mean mm | vertex p95 mm | height error mm | area error "
        "| identity top-1 / 5 / 10 |"
    )
    print("|---|---|---|---|---|---|---|---|")
    view_probabilities = [region(views[:, step]) for step in range(views.shape[1])]
    for name, (spectra, sigma) in answers.items():
        parts = [] if name == TRUE_UNION else view_probabilities  # the five views were the operands
        located_union = localized_region(region(spectra), parts, data.vertex_area, template.mirror)
        located = symmetric_scores(located_union, true_region, data.vertex_area, template.mirror, template.labels)
        bodies = np.stack([models.reconstruct(s, g) for s, g in zip(spectra, sigma, strict=True)])
        score = body_scores(bodies, truth, template.faces)
        rebuilt = closed_spectra(bodies, template.faces, models.k)
        ranked = np.where(open_surface(spectra)[:, None], rebuilt, spectra)
        found = hit_rates(ranked, person, chains.shape, stored, stored_identity)
        print(
            f"| {name} | {100 * located.iou.mean():.1f} % | {100 * located.coverage_error.mean():.1f} | "
            f"{score['vertex_mean_mm']:.0f} | {score['vertex_p95_mm']:.0f} | {score['height_mm']:.0f} | "
            f"{100 * score['area_relative']:.0f} % | "
            + " / ".join(f"{100 * rate:.1f}" for rate in found.values())
            + " % |"
        )


if __name__ == "__main__":
    main()
