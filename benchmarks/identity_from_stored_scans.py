"""Identity from a session against people stored as scans: at rest (the seed) or as a posed scan.

    python -m benchmarks.identity_from_stored_scans [--people 6] [--lengths 3 5 12] [--scans-at-rest]

The seed database stores each person's shape at rest (``models/seed_bodies.npz``); a deployment
stores its own people with ``POST /v1/shapes``, from a whole-body scan in whatever pose they
stood, whose fitted body carries that pose into its shape (``posed_spread`` in
``models/body.npz``). Here the standard build's 63 people are stored both ways: at rest, and as
one closed scan each in a random pose of its own (``--scans-at-rest``: in the rest pose, as a
scanning booth's A-pose), solved, placed and fitted as the route stores it. Test C's people
(among the 63) are scanned as a front-end scans them (registered views, as cut) and their
session prefixes ranked by shape (:func:`app.sessions.identity.shape_distances`) against each
gallery, and by the fitted body's closed spectrum. How often the person scanned comes first.

Needs the ``train`` extra (anny) and the served models in ``models/``.
"""

import argparse
from pathlib import Path

import numpy as np

from app.geometry.shapes import Mesh
from app.inference.models import SpectralModels
from app.retrieval.store import StoredBodies
from app.sessions.body import fitted_session, stored_body
from app.sessions.identity import shape_distances
from training.reconstruction.evaluate import closed_spectrum
from training.sessions.identities import Gallery, rank_of
from training.sessions.reading import session_views
from training.sessions.scans import build_identities, solved_view, test_c_people

POSE_STREAM = 17  # the stored scans' poses: a random stream nothing else draws


def scanned_gallery(models: SpectralModels, at_rest: bool) -> StoredBodies:
    """Each of the standard build's people stored as one closed scan in a random pose of its own
    (``at_rest``: in the rest pose)."""
    from training.data.bodies import AnnySource

    source = AnnySource()
    ids, labels, coefficients, spreads = [], [], [], []
    for number, index, identity, label, _ in build_identities(source):
        rng = np.random.default_rng([POSE_STREAM, number, index])
        body = source.body.pose(identity, source.body.valid_poses(identity, rng, 1, rest_first=at_rest))[0]
        solved = solved_view(Mesh(np.asarray(body, np.float64), models.template.faces))
        stored = stored_body(models.body, models.template.vertices, models.correspondence, solved.part)
        if stored is not None:
            ids.append(label)
            labels.append(label)
            coefficients.append(stored.coefficients)
            spreads.append(stored.spread)
        print(f"stored {label}: {'fitted' if stored is not None else 'no body fits'}", flush=True)
    return StoredBodies(ids, labels, np.array(coefficients), np.array(spreads))


def first(distances: np.ndarray, labels: list[str], label: str) -> bool:
    best: dict[str, float] = {}
    for name, distance in zip(labels, distances, strict=True):
        best[name] = min(best.get(name, np.inf), float(distance))
    return rank_of(best, label) == 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=6)
    parser.add_argument("--lengths", type=int, nargs="+", default=[3, 5, 12])
    parser.add_argument("--scans-at-rest", action="store_true", help="store the scans in the rest pose")
    args = parser.parse_args()
    models = SpectralModels(Path("models"))
    seed = Gallery.seed(Path("models"))
    at_rest = seed.bodies()
    posed = scanned_gallery(models, args.scans_at_rest)
    _, found = test_c_people(args.people)
    rows: dict[int, list[tuple[bool, bool, bool]]] = {length: [] for length in args.lengths}
    for person in found:
        views = session_views(models, person, models.template.faces, "mesh")
        for length in args.lengths:
            fitted = fitted_session(models.body, models.template.vertices, views[:length], registered=True)
            spectrum = closed_spectrum(fitted.vertices(models.body), models.template.faces, models.k)
            rows[length].append(
                (
                    first(shape_distances(fitted, at_rest), at_rest.labels, person.label),
                    first(shape_distances(fitted, posed), posed.labels, person.label),
                    rank_of(seed.person_distances(spectrum), person.label) == 0,
                )
            )
            print(person.label, length, rows[length][-1], flush=True)
    scanned = "a scan at rest" if args.scans_at_rest else "a posed scan"
    print(f"\nscans stored: {len(posed.ids)} of 63 people fitted; spread {models.body.posed_spread:.3f}")
    print(f"| views | sessions | by shape, stored at rest | by shape, stored as {scanned} | by spectrum |")
    print("|---|---|---|---|---|")
    for length, found_rows in rows.items():
        rates = np.mean(found_rows, axis=0) * 100
        print(f"| {length} | {len(found_rows)} | {rates[0]:.1f} % | {rates[1]:.1f} % | {rates[2]:.1f} % |")


if __name__ == "__main__":
    main()
