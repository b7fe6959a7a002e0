"""A session read as a whole: its views in one snapshot and their union, solved only when the
union cached with the session was read from fewer views (or other models). Free of HTTP: the
store's calls run off the event loop, and a registered session's views are fused by whatever
``fuse`` the caller gives (the service's solver workers)."""

from collections.abc import Awaitable, Callable
from dataclasses import dataclass

import anyio
import numpy as np

from app.inference.models import SpectralModels
from app.sessions.fused import View
from app.sessions.records import SessionMeta
from app.sessions.session import SessionUnion, SessionView, session_union, union_by
from app.sessions.store import SessionStore

Fuse = Callable[[list[View], int], Awaitable[np.ndarray]]


@dataclass(frozen=True)
class SessionState:
    """A session, its views in the order they landed, and their union."""

    meta: SessionMeta
    views: list[SessionView]
    union: SessionUnion


async def session_state(store: SessionStore, models: SpectralModels, session_id: str, fuse: Fuse) -> SessionState:
    """The session now: SessionNotFound when it is gone."""
    meta, views = await anyio.to_thread.run_sync(store.views, session_id, len(models.template.vertices))
    union = await anyio.to_thread.run_sync(store.cached_union, session_id, len(views), models.version)
    if union is None:
        union = await _read_union(models, views, meta.registered, fuse)
        await anyio.to_thread.run_sync(store.cache_union, session_id, len(views), models.version, union)
    return SessionState(meta, views, union)


async def _read_union(models: SpectralModels, views: list[SessionView], registered: bool, fuse: Fuse) -> SessionUnion:
    fused = None
    if union_by(len(views), registered) == "fused":
        fused = await fuse([view.geometry for view in views], models.k)
    return await anyio.to_thread.run_sync(session_union, models, views, registered, fused)
