"""``GET /v1/sessions/{id}/body``: the rest-pose body fitted to a session's views, and its measurements.

The fit and the measurements are :mod:`app.sessions.body`'s; here the session is read, the fit
run off the event loop, and the answer shaped. The fit costs a few seconds of one core whatever
the session holds (it reads at most ``FIT_POINTS`` of the views' points).
"""

from typing import Annotated

import anyio
from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from app.api.deps import ModelsDep, SessionsDep
from app.api.problems import DATABASE_SLUGS, MODEL_SLUGS, ProblemError, problem_responses
from app.api.responses import MODEL_VERSION_FIELD
from app.api.routes.sessions import ROUTE, SESSION_SLUGS, SessionId, not_found
from app.inference.bodyfit import NotEnoughSeen
from app.inference.models import SpectralModels
from app.sessions.body import SEEN, NotInOneFrame, SessionBody, session_body
from app.sessions.reading import SessionState, session_state
from app.sessions.records import SessionNotFound
from app.sessions.session import session_cover

router = APIRouter(tags=["sessions"])
BODY_SLUGS = frozenset({"body-unavailable", "body-not-fitted"})


class MeasurementAnswer(BaseModel):
    name: str = Field(description="As ISO 8559-1 names it (docs/measurements.md says how each is taken here).")
    value_m: float = Field(description="On the fitted body, metres.")
    lower_m: float = Field(description="90 % interval, lower end (calibrated on anny sessions).")
    upper_m: float = Field(description="90 % interval, upper end.")


class BodyAnswer(BaseModel):
    id: str = Field(description="The session's id.")
    model_version: str = MODEL_VERSION_FIELD
    views: int = Field(description="The views the body was fitted to.")
    fitted_points: int = Field(description="The views' points the fit read (drawn by area).")
    residual_m: Annotated[float, Field(description="Median gap between those points and the fitted, posed body.")]
    vertices: list[list[float]] = Field(
        description="The fitted body in the rest pose, metres, in the template's vertex order (its faces are the "
        "template's)."
    )
    sigma_m: list[float] = Field(
        description="Each vertex's uncertainty (m), from the fit's posterior: the less the views saw, the larger; "
        "scaled so that 90 % of vertices lie within 1.645 σ of the truth on anny sessions."
    )
    measurements: list[MeasurementAnswer] = Field(description="Those the session's views support.")
    not_measured: dict[str, str] = Field(
        description=f"Measurements left out, with why: the body parts they rest on covered below {SEEN:.0%}."
    )


@router.get(
    ROUTE + "/{session_id}/body",
    response_model=BodyAnswer,
    responses=problem_responses(
        404, 409, 422, 501, 503, slugs=SESSION_SLUGS | BODY_SLUGS | DATABASE_SLUGS | MODEL_SLUGS | {"invalid-request"}
    ),
)
async def session_body_route(
    request: Request, session_id: SessionId, models: ModelsDep, sessions: SessionsDep
) -> BodyAnswer:
    """The body fitted to the session's views (shape and pose together, through their places on the
    template), in the rest pose, with each vertex's uncertainty and the body measurements the views
    support."""
    if models.body is None or models.measurer is None:
        raise ProblemError(501, "body-unavailable", "Body fitting unavailable", "these models have no body.npz")
    try:
        state = await session_state(sessions, models, session_id, request.app.state.solver.session_union)
    except SessionNotFound:
        raise not_found(session_id) from None
    try:
        body = await anyio.to_thread.run_sync(_fitted, models, state)
    except (NotEnoughSeen, NotInOneFrame) as exc:
        raise ProblemError(409, "body-not-fitted", "No body fitted to this session", str(exc)) from None
    return _shaped(session_id, models.version, len(state.views), body)


def _fitted(models: SpectralModels, state: SessionState) -> SessionBody:
    if not state.views:
        raise NotEnoughSeen("the session has no view yet")
    cover = session_cover(state.views)
    coverage = models.region_of(cover.region, cover.share).part_coverage
    return session_body(models.body, models.measurer, state.views, state.meta.registered, coverage)


def _shaped(session_id: str, version: str, views: int, body: SessionBody) -> BodyAnswer:
    return BodyAnswer(
        id=session_id,
        model_version=version,
        views=views,
        fitted_points=body.fitted.points,
        residual_m=body.fitted.residual_m,
        vertices=body.vertices.round(5).tolist(),
        sigma_m=body.sigma.round(5).tolist(),
        measurements=[
            MeasurementAnswer(name=m.name, value_m=m.value, lower_m=m.lower, upper_m=m.upper) for m in body.measurements
        ],
        not_measured=body.not_measured,
    )
