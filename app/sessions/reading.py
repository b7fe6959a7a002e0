"""A session read as a whole: its views in one snapshot and their union, solved only when the
union cached with the session was read from fewer views (or other models). Free of HTTP: the
store's calls run off the event loop, and the views are fused (registered) or aligned and fused
by whatever ``solve`` the caller gives (the service's solver workers)."""

from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import anyio
import numpy as np

from app.inference.models import SpectralModels
from app.sessions.aligned import AlignedUnion
from app.sessions.fused import View
from app.sessions.records import SessionMeta
from app.sessions.session import SessionUnion, SessionView, session_union, union_by
from app.sessions.store import SessionStore

# (views, their points' places on the template, registered, k, a models directory whose body basis
# checks the union's boundary or None) → the spectrum solved on registered views; for views in
# their own frames the union of those that came together, or None where too many were left out
Solve = Callable[[list[View], list[np.ndarray], bool, int, str | None], Awaitable[np.ndarray | AlignedUnion | None]]


@dataclass(frozen=True)
class SessionState:
    """A session, its views in the order they landed, and their union."""

    meta: SessionMeta
    views: list[SessionView]
    union: SessionUnion


async def session_state(store: SessionStore, models: SpectralModels, session_id: str, solve: Solve) -> SessionState:
    """The session now: SessionNotFound when it is gone."""
    meta, views = await anyio.to_thread.run_sync(store.views, session_id, len(models.template.vertices))
    union = await anyio.to_thread.run_sync(store.cached_union, session_id, len(views), models.version)
    if union is None:
        union = await read_union(models, views, meta.registered, solve)
        await anyio.to_thread.run_sync(store.cache_union, session_id, len(views), models.version, union)
    return SessionState(meta, views, union)


async def read_union(models: SpectralModels, views: list[SessionView], registered: bool, solve: Solve) -> SessionUnion:
    """The union as :func:`union_by` reads it; views too many of which cannot be aligned go
    through the chain."""
    union = await views_union(models, views, registered, solve)
    if union is not None:
        return union
    by = union_by(len(views), registered, models.sessions)
    by = by if by in ("empty", "view") else "learned-chain"
    return await anyio.to_thread.run_sync(session_union, models, views, by, None)


async def views_union(
    models: SpectralModels, views: list[SessionView], registered: bool, solve: Solve
) -> SessionUnion | None:
    """The union read from the views' geometry where :func:`union_by` reads it so (fused, or
    aligned and fused, a few left out chained on), solved by ``solve``; None where the learned
    chain reads it (one view, no calibration, a band the calibration gave the chain, or too many
    views that would not align). The fused boundary is checked against the fitted body only
    where every view's place is trusted (a doubted place would claim the wrong template)."""
    by = union_by(len(views), registered, models.sessions)
    if by not in ("fused", "aligned"):
        return None
    geometry, places = [view.geometry for view in views], [view.places for view in views]
    trusted = all(view.located.trusted for view in views)
    seen_with = str(models.directory) if models.body is not None and trusted else None
    solved = await solve(geometry, places, by == "fused", models.k, seen_with)
    if solved is None:
        return None
    return await anyio.to_thread.run_sync(session_union, models, views, by, solved)
