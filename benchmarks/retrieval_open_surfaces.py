"""Identity from an open surface: its own spectrum against the spectrum of the body rebuilt from it.

    python -m benchmarks.retrieval_open_surfaces [--data data/standard] [--models models]

The store holds complete shapes' closed spectra (ShapeDNA, λ₁ = 0). A scan with holes — a whole
body scanned standing, which misses its soles, the top of its head, an armpit — has a boundary,
and its Dirichlet spectrum is another kind of spectrum: λ₁ > 0 and every eigenvalue raised, so
the nearest stored shapes are the smallest bodies, whoever was scanned. ``/v1/retrieve`` ranks
such a query (λ₁ above ``BOUNDARY_RATIO`` · λ₂) through the body the shape decoder rebuilds
from it: the rebuilt body's own closed spectrum, solved by the engine, against the same store.

Queries against the service's seed database (``models/shapes.npz``), each query's own posed
shape left out, top-1/5/10 as the card counts: (a) every third complete posed body of the
benchmark scanned with blind spots (``training.reconstruction.blind_spots``, the card's seed,
σ = 0), also for its unknown people alone, and the same scans uploaded with ``cap_holes=true``
(every hole capped by the service's pipeline, the closed surface's spectrum ranked as it is);
(b) the card's retrieval queries (predicted unions of two parts covering the body), the open ones
alone and all of them as the service ranks them (the closed ones, two operands whose overlap is
not told, by their share profile: each stored shape at its distance to the nearest of the unions
told each share of ``PROFILE_SHARES``); (c) Test A partial
unions (predicted); (d) Test C sessions of five views, chained untold. Prints a Markdown table.
"""

import numpy as np

from app.contract import PROFILE_SHARES
from app.inference.body import open_surface
from app.inference.models import SpectralModels
from benchmarks.arguments import benchmark_parser
from training.common.data import SpectralData
from training.data.pairs import PARTIAL_UNION
from training.data.spectra import MESH
from training.reconstruction.blind_spots import blind_spot_masks, scans_of_shapes
from training.reconstruction.evaluate import (
    BLIND_SPOT_SEED,
    UNKNOWN_GROUPS,
    chained_union,
    identity_groups,
    rebuilt_spectra,
)
from training.union.predictors import served_predictors
from training.union.shapedna import TOP, full_coverage_pairs, hit_rates, stored_bodies

PARTIAL_ROWS = 150  # Test A partial unions scored: enough for a rate to ±4 points
EVERY = 3  # every third stored shape scanned with blind spots


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    args = parser.parse_args()
    data = SpectralData(args.data)
    models = SpectralModels(args.models)
    stored, identity = stored_bodies(data, args.models)
    unknown = np.isin(identity, np.flatnonzero(np.isin(identity_groups(data), UNKNOWN_GROUPS)))
    union = served_predictors(args.models)[0]
    pairs = data.pairs

    rows = np.arange(0, len(stored), EVERY)
    masks = blind_spot_masks(data.template.vertices, len(rows), BLIND_SPOT_SEED)  # as the card's row draws them
    scans, scanned = scans_of_shapes(data, rows, masks, models.k)
    capped_scans, capped_shapes = scans_of_shapes(data, rows, masks, models.k, cap_holes=True)
    full = full_coverage_pairs(pairs)[1]
    full_union, full_sigma = union(full.a, full.b)
    partial = pairs.rows(
        np.flatnonzero((pairs.scenario == PARTIAL_UNION) & (pairs.split == "test_a") & (pairs.variant == MESH))[
            :PARTIAL_ROWS
        ]
    )
    chains = data.chains
    session, session_sigma = chained_union(chains.views, union)
    opened = open_surface(full_union)
    kinds = {
        "complete scans with blind spots": (scans, np.zeros_like(scans), scanned),
        "… of people never trained on": (
            scans[unknown[scanned]],
            np.zeros_like(scans[unknown[scanned]]),
            scanned[unknown[scanned]],
        ),
        "two-part unions covering the body, the open ones": (
            full_union[opened],
            full_sigma[opened],
            full.shape_a[opened],
        ),
        "Test A partial unions": (*union(partial.a, partial.b), partial.shape_a),
        "Test C sessions of 5 views": (session, session_sigma, chains.shape),
    }
    print("| queries | n | open (λ₁ > 1 % λ₂) | own spectrum top-1 / 5 / 10 | rebuilt body's spectrum top-1 / 5 / 10 |")
    print("|---|---|---|---|---|")

    def rates(spectra: np.ndarray, shapes: np.ndarray) -> str:
        found = hit_rates(spectra, identity[shapes], shapes, stored, identity)
        return " / ".join(f"{100 * found[f'top{t}']:.1f}" for t in TOP) + " %"

    print(
        f"| complete scans with blind spots, uploaded with cap_holes=true | {len(capped_shapes)} "
        f"| {100 * open_surface(capped_scans).mean():.0f} % | {rates(capped_scans, capped_shapes)} | — |"
    )
    rebuilt_full = None
    for name, (spectra, sigma, shapes) in kinds.items():
        spectra, sigma = np.asarray(spectra, np.float64), np.asarray(sigma, np.float64)
        rebuilt = rebuilt_spectra(models, spectra, sigma)
        if name.startswith("two-part"):
            rebuilt_full = rebuilt
        print(
            f"| {name} | {len(spectra)} | {100 * open_surface(spectra).mean():.0f} % | {rates(spectra, shapes)} "
            f"| {rates(rebuilt, shapes)} |"
        )
    served = full_union.astype(np.float64)
    served[opened] = rebuilt_full
    print(
        f"| two-part unions covering the body, all (the card's queries), before the share profile | {len(full)} "
        f"| {100 * opened.mean():.0f} % | {rates(full_union, full.shape_a)} | {rates(served, full.shape_a)} |"
    )

    # Each query as (shares, k) spectra: a closed one's share profile, an open one's rebuilt body's
    # spectrum as often (the nearest of identical spectra is that spectrum).
    closed = ~opened
    profiles = np.repeat(served[:, None], len(PROFILE_SHARES), axis=1)
    profiles[closed] = [models.union_profile(a, b) for a, b in zip(full.a[closed], full.b[closed], strict=True)]
    print()
    print("| two-part unions covering the body (the card's queries) | n | top-1 / 5 / 10 |")
    print("|---|---|---|")
    print(
        f"| the closed ones, the untold union's own spectrum | {closed.sum()} "
        f"| {rates(served[closed], full.shape_a[closed])} |"
    )
    print(
        f"| the closed ones, by share profile ({len(PROFILE_SHARES)} shares) | {closed.sum()} "
        f"| {rates(profiles[closed], full.shape_a[closed])} |"
    )
    print(
        f"| all, as `/v1/retrieve` ranks them (closed by share profile, open through the rebuilt body) "
        f"| {len(full)} | {rates(profiles, full.shape_a)} |"
    )


if __name__ == "__main__":
    main()
