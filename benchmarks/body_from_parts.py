"""The body and the identity from two partial scans in frames of their own: fitted against decoded.

    python -m benchmarks.body_from_parts [--people 6] [--pairs 0,12 0,6]

Test C's people (stored in the seed database in ten poses of the build's, none of these), each
scanned as their session scans them, re-meshed; a pair of its far views (by default from the
front and from the back: scanning positions 0 and 12; 0 and 6 are a quarter turn apart), each
sent in a random frame of its own, as ``/v1/reconstruct`` and ``/v1/retrieve`` receive two
uploads. Fitted: the body fitted to the two views' points through their places
(:func:`app.sessions.body.fitted_views`: aligned where they come together, else each in a pose
and frame of its own). Decoded: their union's spectrum (the learned operator told the overlap
their places say) decoded by the shape decoder, as the routes answered before. Mean vertex error
against the person at rest (mm, after a rigid alignment), and whether the person comes first
among the seed database's 63: by the body's closed spectrum (as ``/v1/retrieve`` ranked uploads
before), and, the fitted body, by shape (as it ranks them now, with the first answer's mean
confidence).

Needs the ``train`` extra (anny) and the served models in ``models/``.
"""

import argparse
from pathlib import Path

import numpy as np

from app.inference.models import SpectralModels
from app.sessions.body import NoBodyFits, fitted_views
from app.sessions.chain import Located, folded_union
from app.sessions.identity import ranked_by_shape
from app.sessions.session import session_view
from training.reconstruction.evaluate import closed_spectrum, rigidly_aligned
from training.sessions.identities import Gallery, rank_of
from training.sessions.reading import moved
from training.sessions.scans import Person, solved_view, test_c_people, view_meshes

MODELS = Path("models")


def body_error(vertices: np.ndarray, person: Person) -> float:
    return float(1e3 * np.linalg.norm(rigidly_aligned(vertices, person.rest) - person.rest, axis=1).mean())


def read(models: SpectralModels, gallery: Gallery, person: Person, pair: tuple[int, int], seed: int) -> dict:
    """One pair of views read both ways: each body's error and whether it finds the person first."""
    faces = models.template.faces
    meshes = view_meshes(person, faces, "remeshed")
    solved = [solved_view(meshes[index]) for index in pair]
    placed = [models.correspondence.placed(view.part) for view in solved]
    kept = [session_view("", view, place, []) for view, place in zip(solved, placed, strict=True)]
    frames = moved(kept, np.random.default_rng(seed))
    values = [np.asarray(view.report.eigenvalues) for view in solved]
    union = folded_union(models, values, [Located.placed(p) for p in placed], None, None, None).result
    decoded = models.reconstruct(union.eigenvalues, union.sigma)
    found = {"decoded": scored(models, gallery, person, decoded)}
    try:
        fitted = fitted_views(
            models.body, models.template.vertices, frames, [p.placement.position for p in placed], False
        )
    except NoBodyFits:
        return found | {"fitted": None}
    unknown = models.body.unknown_for(fitted.residual_m)
    first = ranked_by_shape(fitted, gallery.bodies(), 1, models.body.shape_identity_scale, unknown)[0]
    by_shape = (first.label == person.label, first.confidence)
    return found | {"fitted": (*scored(models, gallery, person, fitted.vertices(models.body)), *by_shape)}


def scored(models: SpectralModels, gallery: Gallery, person: Person, body: np.ndarray) -> tuple[float, bool]:
    """A body's error and whether its closed spectrum finds the person first."""
    spectrum = closed_spectrum(body, models.template.faces, models.k)
    return body_error(body, person), rank_of(gallery.person_distances(spectrum), person.label) == 0


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=6)
    parser.add_argument("--pairs", nargs="+", default=["0,12", "0,6"])
    args = parser.parse_args()
    models = SpectralModels(MODELS)
    gallery = Gallery.seed(MODELS)
    _, found = test_c_people(args.people)
    print("| views | pairs | fitted: body mm / first by spectrum, by shape, its confidence | decoded: mm / first |")
    print("|---|---|---|---|")
    for text in args.pairs:
        pair = tuple(int(i) for i in text.split(","))
        rows = [read(models, gallery, person, pair, number) for number, person in enumerate(found)]
        cells = []
        for name in ("fitted", "decoded"):
            done = np.array([row[name] for row in rows if row[name] is not None], dtype=float)
            shares = " / ".join(f"{100 * share:.0f} %" for share in done[:, 1:].mean(axis=0))  # the last: confidence
            fitted = f" ({len(done)} fitted)" if name == "fitted" else ""
            cells.append(f"{done[:, 0].mean():.1f} / {shares}{fitted}")
        print(f"| {pair[0]} and {pair[1]} | {len(rows)} | {cells[0]} | {cells[1]} |")


if __name__ == "__main__":
    main()
