"""``/v1/sessions``: a scanning session that a front-end fills one view at a time.

``POST /v1/sessions`` makes one (its options: registered views, units); ``POST
/v1/sessions/{id}/views`` adds a view (multipart field ``file``, read as every upload is) and
answers the session's union, coverage and what to scan next; ``GET`` reads it; ``DELETE`` ends
it. The session's logic is in :mod:`app.sessions`; here the request is parsed and the answer
shaped.
"""

from datetime import UTC, datetime
from typing import Annotated, Literal

import anyio
import numpy as np
from fastapi import APIRouter, Body, File, Form, Path, Query, Request, Response, UploadFile
from pydantic import BaseModel, ConfigDict, Field

from app.api.deps import ModelsDep, SessionsDep, SettingsDep, region_tokens
from app.api.examples import success
from app.api.operands import upload_options
from app.api.problems import (
    DATABASE_SLUGS,
    MODEL_SLUGS,
    UPLOAD_PROBLEMS,
    UPLOAD_SLUGS,
    ProblemError,
    problem_responses,
)
from app.api.responses import MODEL_VERSION_FIELD, UnionInterval
from app.core.config import Settings
from app.geometry.formats import listed
from app.geometry.io import UNIT_TO_METRES, resolve_file_type
from app.geometry.plausibility import size_warnings
from app.inference.cover import Cover
from app.inference.models import SpectralModels
from app.inference.region_tokens import RegionTokens
from app.sessions.reading import SessionState, session_state
from app.sessions.records import SessionFull, SessionMeta, SessionNotFound
from app.sessions.session import UnionBy, least_covered, session_cover, session_view
from app.sessions.store import SessionStore

router = APIRouter(tags=["sessions"])
ROUTE = "/sessions"
SESSION_SLUGS = frozenset({"session-not-found", "session-full"})
UNAVAILABLE_SLUGS = frozenset({"correspondence-unavailable", "sessions-unavailable"})
SessionId = Annotated[str, Path(max_length=64, description="The session's id, as POST /v1/sessions answered it.")]


class SessionOptions(BaseModel):
    """How a session's views arrive."""

    model_config = ConfigDict(extra="forbid", strict=True)

    registered: bool = Field(
        False,
        description="The views share one coordinate frame and one pose (a tracked scanner's): the union is solved "
        "once on the views themselves, fused (union_by fused). Otherwise each view may come in its own frame: "
        "from as many views as the calibration found it closer, the views are brought into one frame through "
        "their places on the template and fused (aligned); below that, or where they do not come together "
        "(another pose), the learned operator is folded over the views' spectra (learned-chain).",
    )
    units: Literal["m", "cm", "mm"] = Field("m", description="Units of every view's coordinates.")
    scale: float | None = Field(None, gt=0, description="Factor to metres for the views; overrides units.")


class SessionViewAnswer(BaseModel):
    index: int = Field(description="The view's number in the session, in the order the views landed (from 0).")
    source: str = Field(description="The uploaded file's name.")
    eigenvalues: list[float] = Field(description="The view's own spectrum, 1/m².")
    area: float = Field(description="The view's area, m².")
    mean_confidence: float = Field(description="Area-weighted mean confidence of its places on the template.")
    region_token: str | None = Field(
        description="Where it lies on the template (send it in regions beside its spectrum); null where its places "
        "are doubted (a warning says why): its region counts in no coverage or overlap."
    )
    warnings: list[str] = Field(description="What its solve or its placing found doubtful.")


class SessionResponse(UnionInterval):
    id: str = Field(description="The session's id.")
    registered: bool = Field(description="Whether its views share one frame and pose (see SessionOptions).")
    scale: float = Field(description="Factor to metres applied to every view's coordinates.")
    created_at: str = Field(description="When the session was made (ISO 8601, UTC).")
    expires_at: str = Field(description="When it is gone unless a view is added before (ISO 8601, UTC).")
    model_version: str = MODEL_VERSION_FIELD
    views: list[SessionViewAnswer] = Field(description="Its views, in the order they landed.")
    union_by: UnionBy = Field(
        description="What made the union: empty (no view yet), view (one view: its own spectrum, σ 0), fused "
        "(registered views fused and solved once; σ calibrated on anny sessions by view count), aligned (views "
        "in their own frames brought into one through their places on the template, then fused; σ likewise), "
        "aligned-and-chained (aligned so, but a few views, at most a quarter of the session's area, did not come "
        "together: chained onto the others' union by the learned operator; σ of both), learned-chain (the "
        "learned operator folded over the views' spectra in the order they landed, told the overlaps their places "
        "say)."
    )
    overlaps: list[float] = Field(
        description="learned-chain and aligned-and-chained: each union step's overlap read on the template, up to "
        "the first operand whose places are doubted (empty otherwise)."
    )
    overlaps_told: list[bool] = Field(
        description="learned-chain and aligned-and-chained: per step, whether the operator was told it."
    )
    area_fraction: float = Field(description="Share of the template's area the views cover together.")
    part_coverage: dict[str, float] = Field(description="Covered share of each body part's area.")
    least_covered: list[str] = Field(description="The body parts least covered, least first: what to scan next.")
    region_token: str = Field(description="What the views cover together, as a region token.")
    warnings: list[str] = Field(description="Each view's warnings, naming it, and a unit slip between views.")


READ_PROBLEMS = problem_responses(404, 422, 503, slugs=SESSION_SLUGS | DATABASE_SLUGS | MODEL_SLUGS | UPLOAD_SLUGS)


@router.post(
    ROUTE,
    status_code=201,
    response_model=SessionResponse,
    responses={
        **problem_responses(
            400, 422, 501, 503, slugs=DATABASE_SLUGS | MODEL_SLUGS | UNAVAILABLE_SLUGS | {"invalid-form"}
        ),
        **success("session", 201),
    },
)
async def create_session(
    request: Request,
    response: Response,
    models: ModelsDep,
    sessions: SessionsDep,
    settings: SettingsDep,
    options: Annotated[SessionOptions | None, Body(description="Omitted: views unregistered, in metres.")] = None,
) -> SessionResponse:
    """Start a scanning session; add its views with POST /v1/sessions/{id}/views."""
    options = options or SessionOptions()
    if models.correspondence is None:
        raise _unplaceable()
    if options.registered and models.sessions is None:
        raise ProblemError(
            501, "sessions-unavailable", "Registered sessions unavailable", "these models have no sessions.json"
        )
    meta = await anyio.to_thread.run_sync(sessions.create, options.registered, options.units, options.scale)
    response.headers["Location"] = f"{request.url.path}/{meta.id}"
    return await _answer(request, sessions, models, settings, meta.id)


@router.post(
    ROUTE + "/{session_id}/views",
    status_code=201,
    response_model=SessionResponse,
    responses={
        **problem_responses(
            *UPLOAD_PROBLEMS, 404, 409, 501, slugs=UPLOAD_SLUGS | MODEL_SLUGS | SESSION_SLUGS | UNAVAILABLE_SLUGS
        ),
        **success("session_view", 201),
    },
)
async def add_view(
    request: Request,
    session_id: SessionId,
    models: ModelsDep,
    sessions: SessionsDep,
    settings: SettingsDep,
    file: Annotated[UploadFile, File(description="One view: mesh or point cloud, " + listed())],
    file_type: Annotated[str | None, Query(description="Overrides the upload's extension.")] = None,
    boundary: Annotated[str | None, Form(description="Point clouds: JSON list of boundary point indices.")] = None,
) -> SessionResponse:
    """Add a view to the session and answer the session with it: the union of all its views,
    coverage, and the body parts least covered. A view that cannot be read or solved leaves the
    session as it was."""
    if models.correspondence is None:
        raise _unplaceable()
    meta = await _existing(sessions, session_id)
    if meta.views >= settings.session_max_views:  # before the solve: a full session costs nothing
        raise _full(SessionFull.holding(meta.views))
    resolved_type = resolve_file_type(file.filename, file_type)
    data = await file.read()
    options = upload_options(settings, models.k, meta.units, meta.scale, boundary=boundary)
    solved = await request.app.state.solver.solve_with_functions(
        data, resolved_type, options, vectors=False, place_with=models.correspondence.path
    )
    placed = await anyio.to_thread.run_sync(models.correspondence.placed, solved.part, solved.places)
    view = session_view(file.filename or "", solved, placed, list(placed.doubts))
    try:
        await anyio.to_thread.run_sync(sessions.add_view, session_id, view, settings.session_max_views)
    except SessionNotFound:
        raise not_found(session_id) from None
    except SessionFull as exc:
        raise _full(exc) from None
    return await _answer(request, sessions, models, settings, session_id)


@router.get(ROUTE + "/{session_id}", response_model=SessionResponse, responses=READ_PROBLEMS)
async def read_session(
    request: Request, session_id: SessionId, models: ModelsDep, sessions: SessionsDep, settings: SettingsDep
) -> SessionResponse:
    """The session: its views and their union, coverage, and the body parts least covered."""
    return await _answer(request, sessions, models, settings, session_id)


@router.delete(
    ROUTE + "/{session_id}",
    status_code=204,
    responses=problem_responses(404, 422, 503, slugs=SESSION_SLUGS | DATABASE_SLUGS | {"invalid-request"}),
)
async def end_session(session_id: SessionId, sessions: SessionsDep) -> Response:
    """End the session: it and its views are deleted."""
    if not await anyio.to_thread.run_sync(sessions.delete, session_id):
        raise not_found(session_id)
    return Response(status_code=204)


async def _existing(sessions: SessionStore, session_id: str) -> SessionMeta:
    try:
        return await anyio.to_thread.run_sync(sessions.meta, session_id)
    except SessionNotFound:
        raise not_found(session_id) from None


async def _answer(
    request: Request, sessions: SessionStore, models: SpectralModels, settings: Settings, session_id: str
) -> SessionResponse:
    try:
        state = await session_state(sessions, models, session_id, request.app.state.solver.session_union)
    except SessionNotFound:
        raise not_found(session_id) from None
    return _shaped(state, models, await region_tokens(request), settings.session_ttl_seconds)


def _shaped(state: SessionState, models: SpectralModels, tokens: RegionTokens, ttl_seconds: float) -> SessionResponse:
    meta, views, union = state.meta, state.views, state.union
    cover = session_cover(views) or Cover.of_region(np.zeros(len(models.template.vertices), bool))
    region = models.region_of(cover.region, cover.share)
    sources = [f"views[{index}] {view.source}".strip() for index, view in enumerate(views)]
    warnings = [f"{source}: {w}" for source, view in zip(sources, views, strict=True) for w in view.warnings]
    warnings += size_warnings([view.eigenvalues for view in views], sources)
    estimate = union.estimate
    return SessionResponse(
        id=meta.id,
        registered=meta.registered,
        scale=meta.scale if meta.scale is not None else UNIT_TO_METRES[meta.units],
        created_at=_iso(meta.created_at),
        expires_at=_iso(meta.touched_at + ttl_seconds),
        model_version=models.version,
        views=[
            SessionViewAnswer(
                index=index,
                source=view.source,
                eigenvalues=view.eigenvalues.tolist(),
                area=view.located.area,
                mean_confidence=view.located.confidence,
                region_token=tokens.issue(view.located.cover, view.eigenvalues) if view.located.trusted else None,
                warnings=list(view.warnings),
            )
            for index, view in enumerate(views)
        ],
        union_by=union.union_by,
        eigenvalues=estimate.eigenvalues.tolist(),
        sigma=estimate.sigma.tolist(),
        lower=estimate.lower.tolist(),
        upper=estimate.upper.tolist(),
        overlaps=union.overlaps,
        overlaps_told=union.overlaps_told,
        area_fraction=region.area_fraction,
        part_coverage=region.part_coverage,
        least_covered=least_covered(region.part_coverage),
        region_token=tokens.issue(cover, estimate.eigenvalues),
        warnings=warnings,
    )


def _iso(seconds: float) -> str:
    return datetime.fromtimestamp(seconds, UTC).isoformat(timespec="seconds")


def not_found(session_id: str) -> ProblemError:
    return ProblemError(
        404, "session-not-found", "Session not found", f"no session {session_id[:64]!r}: never made, ended or expired"
    )


def _full(error: SessionFull) -> ProblemError:
    return ProblemError(409, "session-full", "Session full", str(error))


def _unplaceable() -> ProblemError:
    return ProblemError(
        501,
        "correspondence-unavailable",
        "Correspondence unavailable",
        "sessions place their views: these models have no correspondence model",
    )
