"""A whole scanning session's union spectrum, by each method, against the exact one.

    python -m benchmarks.session_unions [--people 4] [--variants mesh remeshed] [--seed 7]

Unseen anny people (identities drawn from their own seed, not the training's), each scanned as a
front-end does: a camera at 8 azimuths around the body, each with a far view, a close-up and a
re-scan (24 views in scanning order), then 8 views from above and below (up to 32: a view that sees
no admissible region is left out, so a length a session does not reach has no row). Views arrive as
meshes in the body's frame (registered) or re-meshed (30 % of vertices collapsed). The truth is
the spectrum of the union of the views' template masks, solved by the service's own pipeline
(pin-holes capped). Methods, mean relative error over λ₁…λ₂₀ per session length:

- ``min``: the elementwise minimum of the views' spectra (the trivial union);
- ``chain``: the served learned operator folded view by view, overlaps read from the views'
  places on the template (what ``/v1/union`` answers for spectra sent with their region tokens);
- ``chain told``: the same, told each step's overlap measured from the registered views'
  footprints (``measure_overlap=true``);
- ``fused``: the registered views fused and solved once (glued through their own triangles),
  its boundary checked against the body fitted to them, as a solver worker solves it
  (:mod:`app.sessions.solved`).

Needs the ``train`` extra (anny) and the served models in ``models/``.
"""

import argparse
from pathlib import Path

import numpy as np

from app.geometry.overlap import measured_fold
from app.geometry.pipeline import Solved
from app.inference.correspondence import PlacedPart
from app.inference.models import SpectralModels
from app.sessions.chain import Located, folded_union
from app.sessions.fused import view_of_part
from app.sessions.seen import SeenTemplate
from app.sessions.solved import solved_union
from training.sessions.scans import VARIANTS, K, people, relative_error, solved_view, union_spectrum, view_meshes

LENGTHS = (1, 3, 6, 12, 24, 32)
METHODS = ("min", "chain", "chain told", "fused")


def fused(views: list[Solved], placed: list[PlacedPart], seen: SeenTemplate) -> np.ndarray:
    """The registered views' union as a solver worker solves it."""
    geometry = [view_of_part(view.part) for view in views]
    return solved_union(geometry, [part.placement.position for part in placed], True, K, seen)


def errors(
    models: SpectralModels, views: list[Solved], placed: list[PlacedPart], truth: np.ndarray, seen: SeenTemplate
) -> dict[str, float]:
    values = [np.asarray(v.report.eigenvalues) for v in views]
    found = {
        "min": relative_error(np.min(values, axis=0), truth),
        "fused": relative_error(fused(views, placed, seen), truth),
    }
    if len(views) == 1:
        found["chain"] = found["chain told"] = relative_error(values[0], truth)
        return found
    chained = folded_union(models, values, [Located.placed(part) for part in placed], None, None, None).result
    found["chain"] = relative_error(chained.eigenvalues, truth)
    fold = measured_fold([v.footprint for v in views])
    measured = models.union(values, fold.overlaps, fold.boundaries if models.reads_boundary else None)
    found["chain told"] = relative_error(measured.eigenvalues, truth)
    return found


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=4)
    parser.add_argument("--variants", nargs="+", default=list(VARIANTS), choices=VARIANTS)
    parser.add_argument("--seed", type=int, default=7)
    parser.add_argument("--models", default="models")
    args = parser.parse_args()
    models = SpectralModels(Path(args.models))
    seen = SeenTemplate.of(models.body, models.template)
    sampler, found = people(args.people, args.seed)
    faces = sampler.template.faces
    table: dict[tuple[str, int], list[dict[str, float]]] = {}
    for person in found:
        for variant in args.variants:
            views = [solved_view(mesh) for mesh in view_meshes(person, faces, variant)]
            placed = [models.correspondence.placed(v.part) for v in views]
            for length in LENGTHS:
                if length > len(views):
                    continue
                truth = union_spectrum(person.body, faces, person.masks[:length])
                found_errors = errors(models, views[:length], placed[:length], truth, seen)
                table.setdefault((variant, length), []).append(found_errors)
                print(variant, length, {k: round(v, 4) for k, v in table[(variant, length)][-1].items()}, flush=True)
    print("\n| views | delivery | sessions | " + " | ".join(METHODS) + " |")
    print("|---|---|---|" + "---|" * len(METHODS))
    for (variant, length), rows in sorted(table.items(), key=lambda item: (item[0][1], item[0][0])):
        cells = " | ".join(f"{100 * np.mean([row[m] for row in rows]):.1f} %" for m in METHODS)
        print(f"| {length} | {variant} | {len(rows)} | {cells} |")


if __name__ == "__main__":
    main()
