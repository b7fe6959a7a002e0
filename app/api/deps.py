"""Dependencies shared by the routes."""

from collections import Counter
from collections.abc import Iterable
from typing import Annotated

from fastapi import Depends, Request

from app.api.problems import ProblemError
from app.core.config import Settings

# The one form field a client may repeat: one uploaded scan per ``files`` part.
REPEATABLE_FIELDS = frozenset({"files"})


def app_settings(request: Request) -> Settings:
    """The settings the app was built with (tests build apps with their own)."""
    return request.app.state.settings


SettingsDep = Annotated[Settings, Depends(app_settings)]


async def refuse_repeated_parameters(request: Request) -> None:
    """422 for a query parameter or form field given twice: ``k=500&k=5`` was answered for k = 5,
    silently, and two ``spectra`` fields for the second. FastAPI has already read the form by
    the time dependencies run, so ``request.form()`` is its cached parse, not a second one."""
    _refuse(request.query_params.multi_items(), "query parameter")
    content_type = request.headers.get("content-type", "")
    if content_type.startswith(("multipart/form-data", "application/x-www-form-urlencoded")):
        fields = [(key, value) for key, value in (await request.form()).multi_items() if key not in REPEATABLE_FIELDS]
        _refuse(fields, "form field")


def _refuse(items: Iterable[tuple[str, object]], what: str) -> None:
    repeated = sorted(name for name, count in Counter(name for name, _ in items).items() if count > 1)
    if repeated:
        raise ProblemError(
            422, "invalid-request", "Invalid request", f"{what} {', '.join(repeated)} given more than once"
        )
