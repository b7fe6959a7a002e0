"""What the endpoints depend on — the models and the database — and whether each is usable.

Readiness is the truth: a missing or corrupt artefact, or a database that cannot be reached,
leaves the process up but not ready, and only the endpoints that need the broken part answer
503 (retryable, with the reason). A database that was down at start-up is opened again on the
next request that needs it, so a replica recovers without a restart.
"""

import anyio

from app.api.problems import RETRY_AFTER_UNAVAILABLE, ProblemError
from app.contract import MAX_HOLE_EDGES
from app.core.config import Settings
from app.inference.models import SpectralModels
from app.inference.region_tokens import RegionTokens
from app.retrieval.seed import open_store
from app.retrieval.store import ShapeStore, StoreUnavailable
from app.sessions.store import SessionStore, open_sessions

TOKEN_KEY = "region-tokens"  # the database's key region tokens are signed with, when none is configured


class Resources:
    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self.models: SpectralModels | None = None
        self.models_problem = "not loaded yet"
        self._store: ShapeStore | None = None
        self.store_problem = "not opened yet"
        self._sessions: SessionStore | None = None
        self._tokens: RegionTokens | None = None

    def open(self) -> None:
        """Open both at start-up; failures are recorded, not raised."""
        self._open_models()
        self._open_store()

    def _open_models(self) -> None:
        if self.settings.max_hole_edges != MAX_HOLE_EDGES:
            self.models_problem = (
                f"SPECTRAL_UNIONS_MAX_HOLE_EDGES={self.settings.max_hole_edges} changes the spectrum definition "
                f"the models were trained on (max_hole_edges={MAX_HOLE_EDGES}): spectra are served, unions and "
                "regions are not"
            )
            return
        try:
            self.models = SpectralModels(self.settings.models_dir)
        except Exception as exc:  # any unusable artefact (missing, corrupt, mismatched): not ready, with the reason
            self.models, self.models_problem = None, f"{type(exc).__name__}: {exc}"

    def _open_store(self) -> None:
        """The shape store and the sessions, in one database: both open, or neither is usable."""
        settings = self.settings
        try:
            self._store = open_store(settings.database_path, settings.database_url, settings.models_dir)
            self._sessions = open_sessions(settings.database_path, settings.database_url, settings.session_ttl_seconds)
        except StoreUnavailable as exc:
            self._store, self._sessions, self.store_problem = None, None, str(exc)

    def close(self) -> None:
        """Release what the store holds open (PostgreSQL's idle connections)."""
        for store in (self._store, self._sessions):
            if store is not None:
                store.close()

    def require_models(self) -> SpectralModels:
        if self.models is None:
            retry = {"Retry-After": RETRY_AFTER_UNAVAILABLE}
            raise ProblemError(503, "models-unavailable", "Models unavailable", self.models_problem, retry)
        return self.models

    async def require_store(self) -> ShapeStore:
        if self._store is None:
            await anyio.to_thread.run_sync(self._open_store)
        if self._store is None:
            raise StoreUnavailable(self.store_problem)  # answered as 503 database-unavailable
        return self._store

    async def region_tokens(self) -> RegionTokens:
        """What signs and reads region tokens: under the configured keys, else the database's own
        (503 database-unavailable while it cannot be read)."""
        if self._tokens is None:
            models = self.require_models()
            keys = self.settings.token_keys()
            if keys is None:
                sessions = await self.require_sessions()
                keys = [await anyio.to_thread.run_sync(sessions.service_key, TOKEN_KEY)]
            self._tokens = RegionTokens(keys, models.version)
        return self._tokens

    async def require_sessions(self) -> SessionStore:
        """The scanning sessions' store (the shape store's database), opened again if it was down."""
        await self.require_store()
        if self._sessions is None:  # opened with the shape store, or neither was
            raise StoreUnavailable(self.store_problem)
        return self._sessions

    def summary(self) -> str:
        """One line for the start-up log: what is served, or why it is not."""
        if self.models is None:
            models = f"models unavailable ({self.models_problem})"
        else:
            template = len(self.models.template.vertices)
            placed = "uploads placed on it" if self.models.correspondence else "no correspondence model"
            models = f"models {self.models.version} (k = {self.models.k}, template of {template} vertices, {placed})"
        backend = "postgresql" if self.settings.database_url else f"sqlite {self.settings.database_path}"
        problem = self.store_problem
        try:
            shapes = self._store.count() if self._store else None
        except StoreUnavailable as exc:
            shapes, problem = None, str(exc)
        database = f"{backend} with {shapes} shapes" if shapes is not None else f"{backend} unavailable ({problem})"
        return f"{models}; database {database}"

    async def problems(self) -> list[str]:
        """What keeps the service from being ready (empty when it is)."""
        found = [] if self.models is not None else [f"models: {self.models_problem}"]
        try:
            store = await self.require_store()
            await anyio.to_thread.run_sync(store.ping)
        except StoreUnavailable as exc:
            found.append(f"database: {exc}")
        return found
