"""How well the service measures two views' overlap, and what the union gains from it.

    python -m benchmarks.measured_overlap [--data data/standard] [--models models] [--rows 400]
        [--points 32768] [--split test_c]

Test C's camera-view pairs whose two views are in one pose (the same posed body, as a scanner's
registered views are): each view's part mesh is rebuilt in that pose (re-meshed for the
re-meshed rows, as the data build does), its overlap measured as ``measure_overlap`` does
(:mod:`app.geometry.overlap`), and set against the share from the template's areas. Then the
served union operator's mean relative error untold, told the true share, and told the measured
one; for models that read it, told the measured share and boundary share too (the boundary share
set against the template's edges: :meth:`SpectralData.boundary_shares`). Needs the data set's
``work/shapes.npy`` (the posed bodies); a random subset of ``--rows``.

Then Test C's chains of consecutive views (one posed body each) as the session page sends them:
each view's footprint token, each step measured from the union so far's token and the next
view's (``POST /v1/overlap``), the chain folded untold, told the true shares, told the
measured ones, and told the measured shares and boundary shares.
"""

import numpy as np

from app.geometry.laplacian import mesh_operators
from app.geometry.overlap import (
    FOOTPRINT_POINTS,
    Footprint,
    footprint_from_token,
    footprint_of,
    footprint_token,
    measured_fold,
)
from app.geometry.topology import boundary_vertex_mask
from benchmarks.arguments import benchmark_parser
from training.common.data import SpectralData
from training.common.spectral_errors import spectral_errors
from training.data.spectra import MESH, REMESHED, region_mesh, remeshed
from training.union.predictors import served_predictors, served_told_predictor


def footprint(vertices: np.ndarray, faces: np.ndarray, mask: np.ndarray, variant: str, points: int) -> Footprint:
    """A view as the service would see it uploaded: its part mesh in the posed body's frame,
    kept to ``points`` points (FOOTPRINT_POINTS for an upload, WIRE_POINTS for a footprint token)."""
    mesh = region_mesh(vertices, faces, mask)
    if variant == REMESHED:
        mesh = remeshed(mesh)
    edge = boundary_vertex_mask(mesh.faces, len(mesh.vertices))
    return footprint_of(mesh.vertices, mesh_operators(mesh.vertices, mesh.faces).mass.diagonal(), points, edge=edge)


def main() -> None:
    parser = benchmark_parser(__doc__, models=True)
    parser.add_argument("--rows", type=int, default=400)
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--points", type=int, default=FOOTPRINT_POINTS, help="points kept per view")
    parser.add_argument("--split", default="test_c", help="whose one-pose pairs (validation: to choose a rule on)")
    args = parser.parse_args()
    data = SpectralData(args.data)
    pairs = data.pairs
    one_pose = np.flatnonzero((pairs.split == args.split) & (pairs.shape_a == pairs.shape_b))
    chosen = np.sort(np.random.default_rng(args.seed).choice(one_pose, min(args.rows, len(one_pose)), replace=False))
    rows = pairs.rows(chosen)
    bodies = np.load(args.data / "work" / "shapes.npy", mmap_mode="r")
    faces = data.template.faces
    true = data.overlap_shares(rows.mask_a, rows.mask_b)
    true_boundary = data.boundary_shares(rows.mask_a, rows.mask_b, rows.mask_union)
    folds = [
        measured_fold(
            [
                footprint(
                    np.asarray(bodies[shape], dtype=np.float64), faces, data.masks(np.array([m]))[0], v, args.points
                )
                for m in (mask_a, mask_b)
            ]
        )
        for shape, mask_a, mask_b, v in zip(rows.shape_a, rows.mask_a, rows.mask_b, rows.variant, strict=True)
    ]
    measured = np.array([fold.overlaps[0] for fold in folds])
    boundary = np.array([fold.boundaries[0] for fold in folds])
    union, _ = served_predictors(args.models)
    told = served_told_predictor(args.models)
    if told is None:
        raise SystemExit(f"{args.models} has a union operator that does not read the overlap")
    answers = {
        "untold": union(rows.a, rows.b)[0],
        "told the true share": told(rows.a, rows.b, true)[0],
        "told the measured share": told(rows.a, rows.b, measured)[0],
    }
    if told.reads_boundary:
        answers["told the measured share and boundary share"] = told(rows.a, rows.b, measured, boundary)[0]
    columns = " | ".join(f"{name} mre" for name in answers)
    print(
        "| kind / variant | n | share measured − true: mean abs / p95 / bias | boundary share measured − true: "
        f"mean abs / p95 / bias | {columns} |"
    )
    print("|---" * (4 + len(answers)) + "|")
    for variant in (MESH, REMESHED):
        for kind in (None, *np.unique(rows.scenario)):
            selected = (rows.variant == variant) & ((rows.scenario == kind) if kind else True)
            if not selected.any():
                continue
            gaps = (measured[selected] - true[selected], boundary[selected] - true_boundary[selected])
            truth = rows.union[selected]
            cells = " | ".join(f"{100 * spectral_errors(p[selected], truth)['mre']:.1f} %" for p in answers.values())
            print(f"| {kind or 'all'} / {variant} | {selected.sum()} | {' | '.join(map(_gap, gaps))} | {cells} |")
    session_chains(data, bodies, union, told)


def _gap(gap: np.ndarray) -> str:
    """A measured − true column: mean absolute, 95th percentile absolute, mean."""
    return f"{np.abs(gap).mean():.3f} / {np.quantile(np.abs(gap), 0.95):.3f} / {gap.mean():+.3f}"


def session_chains(data: SpectralData, bodies: np.ndarray, union, told) -> None:
    """Test C's chains measured through footprint tokens step by step, as the session page does."""
    chains = data.chains
    faces = data.template.faces
    token_shares, token_boundaries = [], []
    for shape, masks in zip(chains.shape, chains.view_masks, strict=True):
        body = np.asarray(bodies[shape], dtype=np.float64)
        tokens = [
            footprint_token(footprint(body, faces, data.masks(np.array([m]))[0], MESH, FOOTPRINT_POINTS)) for m in masks
        ]
        shares, boundaries, so_far = [], [], tokens[0]
        for token in tokens[1:]:
            fold = measured_fold([footprint_from_token(so_far), footprint_from_token(token)])
            shares += fold.overlaps
            boundaries += fold.boundaries
            so_far = footprint_token(fold.union)
        token_shares.append(shares)
        token_boundaries.append(boundaries)
    views = chains.views
    true, true_boundary = data.chain_shares(), data.chain_boundaries()
    measured, boundary = np.array(token_shares), np.array(token_boundaries)
    steps = {
        "untold": lambda current, step: union(current, views[:, step])[0],
        "told the true shares": lambda current, step: told(current, views[:, step], true[:, step - 1])[0],
        "told the token-measured shares": lambda current, step: told(current, views[:, step], measured[:, step - 1])[0],
    }
    if told.reads_boundary:
        steps["told the token-measured shares and boundary shares"] = lambda current, step: told(
            current, views[:, step], measured[:, step - 1], boundary[:, step - 1]
        )[0]
    current = dict.fromkeys(steps, views[:, 0])
    print(
        "\n| chain length | n | share measured − true: mean abs / p95 / bias | boundary share measured − true: "
        f"mean abs / p95 / bias | {' | '.join(f'{n} mre' for n in current)} |"
    )
    print("|---" * (4 + len(current)) + "|")
    for step in range(1, views.shape[1]):
        current = {name: advance(current[name], step) for name, advance in steps.items()}
        if step < 2:
            continue
        gaps = (measured[:, :step] - true[:, :step], boundary[:, :step] - true_boundary[:, :step])
        truth = chains.unions[:, step - 1]
        cells = " | ".join(f"{100 * spectral_errors(p, truth)['mre']:.1f} %" for p in current.values())
        print(f"| {step + 1} | {len(truth)} | {' | '.join(map(_gap, gaps))} | {cells} |")


if __name__ == "__main__":
    main()
