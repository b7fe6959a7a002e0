"""Errors as RFC 9457 ``application/problem+json``: one shape for every failure.

Body: ``{"type": "/problems/<slug>", "title": ..., "status": ..., "detail": ...}``. The slug
is stable and documented in the README, so clients can branch on it.
"""

import errno

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from pydantic import BaseModel
from starlette.exceptions import HTTPException
from starlette.routing import Match

from app.core.errors import InputError
from app.geometry.errors import UnsupportedFileType
from app.geometry.formats import listed
from app.retrieval.store import StoreUnavailable

PROBLEM_MEDIA_TYPE = "application/problem+json"
RETRY_AFTER_UNAVAILABLE = "5"  # seconds: a restarting database or a replaced model file


class Problem(BaseModel):
    """The error body of every non-2xx response."""

    type: str
    title: str
    status: int
    detail: str


class ProblemError(HTTPException):
    """An HTTP error that already knows its problem slug and title."""

    def __init__(self, status: int, slug: str, title: str, detail: str, headers: dict[str, str] | None = None) -> None:
        super().__init__(status_code=status, detail=detail, headers=headers)
        self.slug = slug
        self.title = title


def problem_response(status: int, slug: str, title: str, detail: str) -> JSONResponse:
    body = Problem(type=f"/problems/{slug}", title=title, status=status, detail=detail)
    return JSONResponse(body.model_dump(), status_code=status, media_type=PROBLEM_MEDIA_TYPE)


def status_for(error: InputError) -> int:
    """415 for a type outside the allow-list; 422 for everything the file itself got wrong."""
    return 415 if isinstance(error, UnsupportedFileType) else 422


# Representative problems per status for the OpenAPI page: (slug, title, detail).
EXAMPLES: dict[int, list[tuple[str, str, str]]] = {
    400: [("invalid-form", "Invalid form data", "Too many files. Maximum number of files is 32.")],
    401: [("invalid-api-key", "Invalid API key", "X-API-Key is missing or wrong")],
    403: [("writes-disabled", "Writes disabled", "no API key is configured on this server")],
    404: [
        ("shape-not-found", "Shape not found", "no shape with id 3f2a9c"),
        ("session-not-found", "Session not found", "no session '5d1c…': never made, ended or expired"),
    ],
    408: [
        (
            "body-timeout",
            "Request body too slow",
            "the request body was not complete 60 s after its headers (12288 bytes received)",
        )
    ],
    409: [
        ("session-full", "Session full", "the session holds 32 views, as many as this service keeps"),
        ("body-not-fitted", "No body fitted to this session", "120 points: a body needs at least 200 seen"),
    ],
    413: [("upload-too-large", "Upload too large", "the request body exceeds the cap of 67108864 bytes")],
    415: [
        (
            "unsupported-file-type",
            "Unsupported file type",
            f"file type 'zip' is not accepted; allowed: {listed()}",
        )
    ],
    422: [
        ("invalid-spectrum", "Invalid spectrum", "spectra[1] is not in ascending order"),
        ("invalid-overlap", "Invalid overlap", "2 overlaps for 2 operands: give one per union step (1)"),
        ("invalid-region", "Invalid region", "regions[0] holds 1528 bits, not this template's 12167 vertices"),
        (
            "untrusted-region",
            "Region token not trusted",
            "regions[1] was issued for another part's spectrum than the one sent with it",
        ),
        ("invalid-geometry", "Invalid geometry", "files[0] scan.ply: 1 vertices have NaN or infinite coordinates"),
        (
            "implausible-size",
            "No body part is this size",
            "files[0] scan.ply: the shape's area is 1.39e+06 m², outside the 0.01–10 m² of a human scan; read in mm "
            "it would be 1.39 m² (units=mm): not placed on the body",
        ),
        ("invalid-request", "Invalid request", "query.top: Input should be less than or equal to 100"),
        (
            "too-many-faces",
            "Too many faces",
            "files[0] scan.ply: the PLY header declares 900000000 faces; the cap is 400000",
        ),
        (
            "scene-too-large",
            "Scene too large",
            "files[0] scan.glb: the GLB scene has 30000 nodes; at most 1000 are accepted",
        ),
        ("solve-timeout", "Solve ran past its deadline", "files[0] scan.ply: the solve did not finish within 120 s"),
        (
            "solve-memory-exceeded",
            "Solve needs too much memory",
            "files[0] scan.ply: the solve needed more memory than a solver worker may use",
        ),
    ],
    501: [
        ("reconstruction-unavailable", "Reconstruction unavailable", "these models have no shape decoder"),
        ("correspondence-unavailable", "Correspondence unavailable", "these models have no correspondence model"),
        ("sessions-unavailable", "Registered sessions unavailable", "these models have no sessions.json"),
        ("body-unavailable", "Body fitting unavailable", "these models have no body.npz"),
    ],
    503: [
        (
            "not-ready",
            "Not ready",
            "models: ModelsCorrupt: localizer.onnx does not match its checksum in MANIFEST.json",
        ),
        ("models-unavailable", "Models unavailable", "ModelsCorrupt: union.onnx is missing from /srv/models"),
        ("database-unavailable", "Database unavailable", "PostgreSQL: connection refused"),
        (
            "overloaded",
            "Overloaded",
            "18 solves (6291456 bytes of their uploads) are already being received or run; retry after 1 s.",
        ),
        ("solver-crashed", "Solver crashed", "the solver process stopped during the solve (…); retry."),
        ("upload-storage-full", "Upload storage full", "the server has no temporary space left to receive this upload"),
    ],
}


# What any route that takes an uploaded file can answer besides its own errors: the statuses,
# and the documented problems among them (a route adds those of what else it needs).
UPLOAD_PROBLEMS = (400, 408, 413, 415, 422, 503)
UPLOAD_SLUGS = frozenset(
    {
        "invalid-form",
        "body-timeout",
        "upload-too-large",
        "unsupported-file-type",
        "invalid-geometry",
        "invalid-request",
        "too-many-faces",
        "scene-too-large",
        "solve-timeout",
        "solve-memory-exceeded",
        "overloaded",
        "solver-crashed",
        "upload-storage-full",
    }
)
MODEL_SLUGS = frozenset(
    {
        "invalid-spectrum",
        "invalid-overlap",
        "invalid-region",
        "untrusted-region",
        "implausible-size",
        "models-unavailable",
    }
)  # routes that run the models
DATABASE_SLUGS = frozenset({"database-unavailable"})  # routes that read or write the store


def problem_responses(*statuses: int, slugs: set[str] | None = None) -> dict[int | str, dict]:
    """OpenAPI ``responses=`` entries for the given statuses: the Problem body with examples
    (those of ``slugs`` only, when a route can raise just some of them)."""
    return {status: _documented(status, slugs) for status in statuses}


def _documented(status: int, slugs: set[str] | None) -> dict:
    examples = {
        slug: {"summary": title, "value": {"type": f"/problems/{slug}", "title": title, "status": status, "detail": d}}
        for slug, title, d in EXAMPLES.get(status, [])
        if slugs is None or slug in slugs
    }
    content = {PROBLEM_MEDIA_TYPE: {"schema": Problem.model_json_schema(), "examples": examples}}
    return {"content": content, "description": "Problem"}


# Errors raised by Starlette/FastAPI themselves, which carry no slug: a multipart body that is
# malformed or over the form limits (too many files or fields, a text field over its size) is 400.
FRAMEWORK_PROBLEMS = {
    400: ("invalid-form", "Invalid form data"),
    404: ("not-found", "Not found"),
    405: ("method-not-allowed", "Method not allowed"),
}


def _out_of_spool_space(exc: HTTPException) -> bool:
    """Whether parsing the form failed because the disk behind uploaded-file spooling is full.
    FastAPI reports every parse failure as a 400; this one is the server's, so 503."""
    cause = exc.__cause__
    return isinstance(cause, OSError) and cause.errno in (errno.ENOSPC, errno.EDQUOT)


def _allowed_methods(request: Request) -> list[str]:
    """Every method some route serves at this path. Starlette's own 405 names only the first
    route that matched the path, so GET and POST /v1/shapes (two routes) would hide each other."""
    methods: set[str] = set()
    for route in request.app.routes:
        match, _ = route.matches({**request.scope, "method": "\0"})
        if match is not Match.NONE:
            methods |= getattr(route, "methods", None) or set()
    return sorted(methods)


async def form_items(request: Request) -> list[tuple[str, object]]:
    """A request's form fields, (name, value) as sent, repeats included; none for a request that
    is no form. FastAPI has read the form before dependencies and handlers run, so this is its
    cached parse, not a second one."""
    media_type = request.headers.get("content-type", "").split(";")[0].strip().lower()  # as Starlette reads it
    if media_type not in ("multipart/form-data", "application/x-www-form-urlencoded"):
        return []
    return list((await request.form()).multi_items())


async def _sent_fields(request: Request) -> list[str]:
    """The names of the form fields a request sent, quoted."""
    try:
        items = await form_items(request)
    except Exception:  # a form that cannot be parsed was answered 400 before validation
        return []
    return sorted({f"'{name}'" for name, _ in items})


def install_problem_handlers(app: FastAPI) -> None:
    """Route every error through the one problem+json shape; none leaks as HTML or plain text."""

    @app.exception_handler(InputError)
    async def _input(_: Request, exc: InputError) -> JSONResponse:
        return problem_response(status_for(exc), exc.slug, exc.title, str(exc))

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        detail = "; ".join(f"{'.'.join(str(p) for p in err['loc'])}: {err['msg']}" for err in exc.errors())
        missing = [err for err in exc.errors() if err.get("type") == "missing" and err["loc"][:1] == ("body",)]
        sent = await _sent_fields(request) if missing else []
        if sent:  # a field sent under another name: say which, so the client sees what it did
            detail += f" (it sent {', '.join(sent)})"
        return problem_response(422, "invalid-request", "Invalid request", detail)

    @app.exception_handler(StoreUnavailable)
    async def _store(_: Request, exc: StoreUnavailable) -> JSONResponse:
        response = problem_response(503, "database-unavailable", "Database unavailable", str(exc))
        response.headers["Retry-After"] = RETRY_AFTER_UNAVAILABLE
        return response

    @app.exception_handler(HTTPException)
    async def _http(request: Request, exc: HTTPException) -> JSONResponse:
        if _out_of_spool_space(exc):
            exc = ProblemError(
                503,
                "upload-storage-full",
                "Upload storage full",
                "the server has no temporary space left to receive this upload; retry later.",
                headers={"Retry-After": RETRY_AFTER_UNAVAILABLE},
            )
        slug, title = FRAMEWORK_PROBLEMS.get(exc.status_code, (f"http-{exc.status_code}", str(exc.detail)))
        slug, title = getattr(exc, "slug", slug), getattr(exc, "title", title)
        response = problem_response(exc.status_code, slug, title, str(exc.detail))
        response.headers.update(exc.headers or {})
        if exc.status_code == 405:
            response.headers["Allow"] = ", ".join(_allowed_methods(request))
        return response

    @app.exception_handler(Exception)
    async def _unexpected(_: Request, exc: Exception) -> JSONResponse:
        return problem_response(500, "internal-error", "Internal error", type(exc).__name__)
