"""A session's union solved on its views, as a solver worker solves it and as its evaluation
reads it: registered views fused once, views in their own frames aligned through their places
first; either with its boundary checked against the body fitted to the views where a body basis
is served (:mod:`app.sessions.seen`)."""

from functools import partial

import numpy as np

from app.sessions.aligned import AlignedUnion, aligned_union
from app.sessions.fused import View, fused_spectrum
from app.sessions.seen import SeenTemplate, deep_inside


def solved_union(
    views: list[View], places: list[np.ndarray], registered: bool, k: int, seen: SeenTemplate | None
) -> np.ndarray | AlignedUnion | None:
    """The first ``k`` eigenvalues of the union of ``registered`` views (one frame), or the
    union of those of the views in their own frames that came together (None where too many did
    not); ``places``: each view's points' places on the template; ``seen``: the body basis and
    template that check the fused boundary, or None."""
    inside = None if seen is None else partial(deep_inside, seen)
    if registered:
        return fused_spectrum(views, k, places, inside)
    return aligned_union(views, places, k, inside=inside)
