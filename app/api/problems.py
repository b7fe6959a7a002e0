"""Errors as RFC 9457 ``application/problem+json``: one shape for every failure.

Body: ``{"type": "/problems/<slug>", "title": ..., "status": ..., "detail": ...}``. The slug
is stable and documented in the README, so clients can branch on it.
"""

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException

from app.geometry.errors import GeometryError, UnsupportedFileType

PROBLEM_MEDIA_TYPE = "application/problem+json"


class Problem(BaseModel):
    """The error body of every non-2xx response."""

    type: str
    title: str
    status: int
    detail: str


class ProblemError(HTTPException):
    """An HTTP error that already knows its problem slug and title."""

    def __init__(self, status: int, slug: str, title: str, detail: str) -> None:
        super().__init__(status_code=status, detail=detail)
        self.slug = slug
        self.title = title


def problem_response(status: int, slug: str, title: str, detail: str) -> JSONResponse:
    body = Problem(type=f"/problems/{slug}", title=title, status=status, detail=detail)
    return JSONResponse(body.model_dump(), status_code=status, media_type=PROBLEM_MEDIA_TYPE)


def status_for(error: GeometryError) -> int:
    """415 for a type outside the allow-list; 422 for everything the file itself got wrong."""
    return 415 if isinstance(error, UnsupportedFileType) else 422


def problem_responses(*statuses: int) -> dict[int | str, dict]:
    """OpenAPI ``responses=`` entries for the given statuses, all with the Problem body."""
    return {
        status: {"model": Problem, "content": {PROBLEM_MEDIA_TYPE: {}}, "description": "Problem"} for status in statuses
    }


def install_problem_handlers(app: FastAPI) -> None:
    """Route every error through the one problem+json shape; none leaks as HTML or plain text."""

    @app.exception_handler(GeometryError)
    async def _geometry(_: Request, exc: GeometryError) -> JSONResponse:
        return problem_response(status_for(exc), exc.slug, exc.title, str(exc))

    @app.exception_handler(RequestValidationError)
    async def _validation(_: Request, exc: RequestValidationError) -> JSONResponse:
        detail = "; ".join(f"{'.'.join(str(p) for p in err['loc'])}: {err['msg']}" for err in exc.errors())
        return problem_response(422, "invalid-request", "Invalid request", detail)

    @app.exception_handler(HTTPException)
    async def _http(_: Request, exc: HTTPException) -> JSONResponse:
        slug = getattr(exc, "slug", f"http-{exc.status_code}")
        title = getattr(exc, "title", str(exc.detail))
        response = problem_response(exc.status_code, slug, title, str(exc.detail))
        response.headers.update(exc.headers or {})
        return response

    @app.exception_handler(Exception)
    async def _unexpected(_: Request, exc: Exception) -> JSONResponse:
        return problem_response(500, "internal-error", "Internal error", type(exc).__name__)
