"""Dependencies shared by the routes: settings, the models, the store, the write key, what a
union request tells of its steps."""

import hmac
from collections import Counter
from collections.abc import Iterable
from typing import Annotated

from fastapi import Depends, Header, Request

from app.api.operands import Told, told_query
from app.api.problems import ProblemError, form_items
from app.core.config import Settings
from app.inference.models import SpectralModels
from app.inference.region_tokens import RegionTokens
from app.retrieval.store import ShapeStore
from app.sessions.store import SessionStore

# The one form field a client may repeat: one uploaded scan per ``files`` part.
REPEATABLE_FIELDS = frozenset({"files"})


def app_settings(request: Request) -> Settings:
    """The settings the app was built with (tests build apps with their own)."""
    return request.app.state.settings


SettingsDep = Annotated[Settings, Depends(app_settings)]


def loaded_models(request: Request) -> SpectralModels:
    """The served models, or 503 models-unavailable with the reason they are not."""
    return request.app.state.resources.require_models()


ModelsDep = Annotated[SpectralModels, Depends(loaded_models)]


async def usable_store(request: Request) -> ShapeStore:
    """The ShapeDNA store, opened again if it was down; 503 database-unavailable if it still is."""
    return await request.app.state.resources.require_store()


StoreDep = Annotated[ShapeStore, Depends(usable_store)]


async def usable_sessions(request: Request) -> SessionStore:
    """The scanning sessions' store; 503 database-unavailable while the database is down."""
    return await request.app.state.resources.require_sessions()


SessionsDep = Annotated[SessionStore, Depends(usable_sessions)]


async def region_tokens(request: Request) -> RegionTokens:
    """What signs and reads region tokens (503 when its key cannot be read from the database)."""
    return await request.app.state.resources.region_tokens()


TokensDep = Annotated[RegionTokens, Depends(region_tokens)]
# The union routes' overlap, boundary and measure_overlap query parameters, as one.
ToldDep = Annotated[Told, Depends(told_query)]


def require_write_key(settings: SettingsDep, x_api_key: Annotated[str | None, Header()] = None) -> None:
    """Writes need the ``X-API-Key`` header to match the configured key (compared in constant
    time); with no key configured, writes are refused outright."""
    expected = settings.api_key.get_secret_value() if settings.api_key else None
    if expected is None:
        raise ProblemError(403, "writes-disabled", "Writes disabled", "no API key is configured on this server")
    if x_api_key is None or not hmac.compare_digest(x_api_key.encode(), expected.encode()):
        raise ProblemError(401, "invalid-api-key", "Invalid API key", "X-API-Key is missing or wrong")


WriteKeyDep = Depends(require_write_key)


async def refuse_repeated_parameters(request: Request) -> None:
    """422 for a query parameter or form field given twice: ``k=500&k=5`` was answered for k = 5,
    silently, and two ``spectra`` fields for the second."""
    _refuse(request.query_params.multi_items(), "query parameter")
    _refuse([(key, value) for key, value in await form_items(request) if key not in REPEATABLE_FIELDS], "form field")


def _refuse(items: Iterable[tuple[str, object]], what: str) -> None:
    repeated = sorted(name for name, count in Counter(name for name, _ in items).items() if count > 1)
    if repeated:
        raise ProblemError(
            422, "invalid-request", "Invalid request", f"{what} {', '.join(repeated)} given more than once"
        )
