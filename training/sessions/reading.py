"""One anny session read every way the service can read it, each prefix against its exact union.

Each view is solved and placed as an upload is; registered views are fused as they are; views in
their own frames are the same views each moved by a random rigid motion (seeded), as an
untracked scanner would send them, then aligned through their places and fused (either as a
solver worker solves them, :func:`app.sessions.solved.solved_union`); the learned
chain and the elementwise minimum read the views' spectra. Shared by the calibration
(:mod:`training.sessions.calibrate`) and the card's evaluation.
"""

from dataclasses import dataclass, replace

import numpy as np
from scipy.spatial.transform import Rotation

from app.inference import SpectralModels, UnionEstimate
from app.sessions import (
    AlignedUnion,
    SeenTemplate,
    SessionView,
    View,
    chained_onto_aligned,
    session_union,
    session_view,
    solved_union,
)
from training.sessions.scans import K, Person, solved_view, union_spectrum, view_meshes


@dataclass(frozen=True)
class Read:
    """One session prefix: its length, the truth, and each reading's spectrum and σ (aligned:
    None where the views did not all come together; partly: where a few did not, the others
    aligned and those chained onto them, its σ the chain's alone, None otherwise)."""

    views: int
    truth: np.ndarray
    elementwise_min: np.ndarray
    chain: np.ndarray
    chain_sigma: np.ndarray
    fused: np.ndarray
    aligned: np.ndarray | None
    partly: UnionEstimate | None = None

    def unregistered_aligned(self) -> np.ndarray:
        """The spectrum an unregistered session read aligned is answered: aligned, else aligned
        and chained, else the chain."""
        if self.aligned is not None:
            return self.aligned
        return self.chain if self.partly is None else self.partly.eigenvalues


def session_views(models: SpectralModels, person: Person, faces: np.ndarray, variant: str) -> list[SessionView]:
    """The person's views solved and placed as uploads are, in scanning order."""
    views = []
    for index, mesh in enumerate(view_meshes(person, faces, variant)):
        solved = solved_view(mesh)
        placed = models.correspondence.placed(solved.part)
        views.append(session_view(f"view{index}", solved, placed, []))
    return views


def moved(views: list[SessionView], rng: np.random.Generator) -> list[View]:
    """Each view's geometry under a random rotation and a translation of about a metre."""
    out = []
    for view in views:
        w, x, y, z = rng.normal(size=4)  # a uniform random rotation: a normal quaternion, normalized
        rotation = Rotation.from_quat([x, y, z, w]).as_matrix()
        out.append(replace(view.geometry, points=view.geometry.points @ rotation.T + rng.normal(size=3)))
    return out


def read_prefixes(
    models: SpectralModels,
    person: Person,
    faces: np.ndarray,
    views: list[SessionView],
    lengths: tuple[int, ...],
    rng: np.random.Generator,
) -> list[Read]:
    """Every prefix of the session in ``lengths`` (those it reaches), read every way."""
    frames = moved(views, rng)
    seen = SeenTemplate.of(models.body, models.template)
    found = []
    for length in lengths:
        if length > len(views):
            continue
        prefix = views[:length]
        chained = session_union(models, prefix, "learned-chain").estimate
        places = [view.places for view in prefix]
        aligned = solved_union(frames[:length], places, False, K, seen)
        found.append(
            Read(
                length,
                union_spectrum(person.body, faces, person.masks[:length]),
                np.min([view.eigenvalues for view in prefix], axis=0),
                chained.eigenvalues,
                chained.sigma,
                solved_union([view.geometry for view in prefix], places, True, K, seen),
                aligned.eigenvalues if _whole(aligned, length) else None,
                _partly(models, prefix, aligned),
            )
        )
    return found


def _whole(aligned: AlignedUnion | None, views: int) -> bool:
    """Whether every one of ``views`` views came together."""
    return aligned is not None and len(aligned.joined) == views


def _partly(models: SpectralModels, views: list[SessionView], aligned: AlignedUnion | None) -> UnionEstimate | None:
    """Where some views did not come together (within the share left out the service allows):
    the others fused, those chained onto them, as the service reads them."""
    if aligned is None or _whole(aligned, len(views)):
        return None
    return chained_onto_aligned(models, views, aligned).estimate
