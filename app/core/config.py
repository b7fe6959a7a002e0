"""One typed settings object, read from ``SPECTRAL_UNIONS_*`` environment variables."""

import os
from functools import lru_cache
from pathlib import Path

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from app.contract import MAX_HOLE_EDGES
from app.geometry.placing import PLACED_VERTICES

MIN_KEY_CHARACTERS = 16


class Settings(BaseSettings):
    """Service settings; every field can be overridden by ``SPECTRAL_UNIONS_<FIELD>``."""

    model_config = SettingsConfigDict(env_prefix="SPECTRAL_UNIONS_")

    max_upload_bytes: int = Field(
        64 * 1024 * 1024, gt=0, description="Largest request body accepted, counted while streaming."
    )
    max_vertices: int = Field(100_000, gt=0, description="Vertex cap for an uploaded shape.")
    max_hole_edges: int = Field(
        MAX_HOLE_EDGES,
        ge=0,
        description="Boundary loops up to this many edges are pin-holes and get filled. Part of the spectrum "
        "definition the models are trained on: another value serves spectra, but not unions or regions.",
    )
    placed_vertices: int = Field(
        PLACED_VERTICES,
        ge=500,
        description="A mesh with more vertices is placed on the template through its copy simplified to about this "
        "many (each vertex taking the place of the copy's vertex it collapsed into): fewer is faster and less exact.",
    )
    models_dir: Path = Field(
        Path(__file__).resolve().parents[2] / "models",
        description="Directory with union.onnx, localizer.onnx and the template (the repository's models/).",
    )
    database_path: Path = Field(
        Path("spectral-unions.sqlite"),
        description="SQLite file of the ShapeDNA store; created and seeded from models/shapes.npz when new.",
    )
    database_url: str | None = Field(
        None, pattern=r"^postgres(ql)?://", description="PostgreSQL URL; replaces the SQLite file (replicas share it)."
    )
    api_key: SecretStr | None = Field(None, description="Key for writes to /v1/shapes; writes are refused without.")
    region_token_keys: SecretStr | None = Field(
        None,
        description="Comma-separated keys (16 characters or more) region tokens are signed with: the first signs, "
        "every one is accepted. Rotate by putting a new key first and keeping the old one listed while clients may "
        "still hold its tokens (at least the session time-to-live). Unset: one key the service makes and keeps in "
        "its database, shared by replicas.",
    )
    solver_concurrency: int = Field(
        default_factory=lambda: max(1, os.cpu_count() or 1),
        gt=0,
        description="Eigen-solves running at once; more requests wait for a slot.",
    )
    max_queued_solves: int = Field(
        16,
        ge=0,
        description="Upload requests that may wait for a solve slot, counted on their headers; "
        "beyond them, 503 overloaded with Retry-After before the body is read.",
    )
    max_inflight_upload_bytes: int = Field(
        512 * 1024 * 1024,
        gt=0,
        description="Body bytes of the upload requests in flight, counted as they arrive; beyond, 503 overloaded.",
    )
    body_timeout_seconds: float = Field(
        60.0, gt=0, description="Time a client has to send a request body once its headers arrived; beyond, 408."
    )
    solve_timeout_seconds: float = Field(
        120.0, gt=0, description="Deadline of one solve; its worker is stopped and the client gets 422 solve-timeout."
    )
    solve_memory_mb: int = Field(
        4096, ge=0, description="Address-space cap of a solver worker (0: none); beyond it, 422 solve-memory-exceeded."
    )
    solves_per_worker: int = Field(
        500, ge=0, description="Solves after which a solver worker is replaced by a fresh one (0: never)."
    )
    session_max_views: int = Field(
        32,
        gt=0,
        description="Views a scanning session keeps; a view beyond is refused (409 session-full), the session kept.",
    )
    session_ttl_seconds: float = Field(
        24 * 3600.0,
        gt=0,
        description="A scanning session untouched (no view added) for this long is gone: 404, its views deleted.",
    )
    shutdown_grace_seconds: float = Field(
        30.0, gt=0, description="On SIGTERM, how long in-flight requests may take to finish before they are cancelled."
    )

    @field_validator("region_token_keys")
    @classmethod
    def _keys_long_enough(cls, value: SecretStr | None) -> SecretStr | None:
        """A short key is guessed: refused at start-up rather than signing with it."""
        if value is not None:
            if not all(len(key) >= MIN_KEY_CHARACTERS for key in _listed(value)):
                raise ValueError(f"every region token key needs {MIN_KEY_CHARACTERS} characters or more")
        return value

    def token_keys(self) -> list[bytes] | None:
        """The configured region token keys, the signing one first (None: none configured)."""
        return None if self.region_token_keys is None else [key.encode() for key in _listed(self.region_token_keys)]


def _listed(keys: SecretStr) -> list[str]:
    return [key.strip() for key in keys.get_secret_value().split(",")]


@lru_cache
def get_settings() -> Settings:
    """Settings built on first use, not at import, so tests can pass their own."""
    return Settings()
