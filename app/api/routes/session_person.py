"""The person a session scanned: ``GET /v1/sessions/{id}/body``, the rest-pose body fitted to its
views and its measurements; ``GET /v1/sessions/{id}/identity``, the stored people nearest that body.

The fit, the measurements and the ranking are :mod:`app.sessions`'s; here the session is read, the
fit run off the event loop, the body's spectrum solved on the solver pool, and the answer shaped.
A fit costs a few seconds of one core whatever the session holds (it reads at most
``FIT_POINTS`` of the views' points); both routes are admitted like uploads (``app.main``).
"""

from collections.abc import Callable
from typing import Annotated, Literal, TypeVar

import anyio
from fastapi import APIRouter, Query, Request
from pydantic import BaseModel, Field

from app.api.deps import ModelsDep, SessionsDep, StoreDep
from app.api.examples import success
from app.api.problems import DATABASE_SLUGS, MODEL_SLUGS, ProblemError, problem_responses
from app.api.rebuilt import solved_body
from app.api.responses import MODEL_VERSION_FIELD, PersonAnswer, answered, answered_people
from app.api.routes.sessions import ROUTE, SESSION_SLUGS, SessionId, not_found
from app.inference.bodyfit import FittedBody, NotEnoughSeen
from app.inference.models import SpectralModels
from app.sessions.body import SEEN, NoBodyFits, SessionBody, fitted_session, session_body
from app.sessions.identity import SHAPES_PER_PERSON, shape_ranking
from app.sessions.reading import SessionState, session_state
from app.sessions.records import SessionNotFound
from app.sessions.session import session_coverage
from app.sessions.store import SessionStore

T = TypeVar("T")

router = APIRouter(tags=["sessions"])
BODY_SLUGS = frozenset({"body-unavailable", "body-not-fitted"})
BODY, IDENTITY = "/body", "/identity"  # under a session's path; both fit a body (app.main admits them)
MAX_TOP = 20


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


class IdentityAnswer(BaseModel):
    id: str = Field(description="The session's id.")
    model_version: str = MODEL_VERSION_FIELD
    views: int = Field(description="The views the body was fitted to.")
    ranked_by: Literal["shape", "fitted_body"] = Field(
        description="shape: the stored shapes that have a body ranked by how far their person's shape coefficients "
        "are from the body fitted to the session's views, under what the views left uncertain; fitted_body (where "
        "no stored shape has a body): by their ShapeDNA distance to that body's closed spectrum."
    )
    looked_up: list[float] | None = Field(
        description="Ranked by fitted_body: the fitted body's closed spectrum, 1/m² (null when ranked by shape)."
    )
    people: list[PersonAnswer] = Field(description="One per stored person, nearest first.")
    warnings: list[str] = Field(
        description="When the first person is not clearly ahead of the others; by shape, when even the nearest "
        "stored person is farther than stored people's own scans lie (probably someone not stored), and how many "
        "stored shapes have no body to rank."
    )


PERSON_PROBLEMS = problem_responses(
    404, 409, 422, 501, 503, slugs=SESSION_SLUGS | BODY_SLUGS | DATABASE_SLUGS | MODEL_SLUGS | {"invalid-request"}
)


@router.get(
    ROUTE + "/{session_id}" + BODY, response_model=BodyAnswer, responses=PERSON_PROBLEMS | success("session_body")
)
async def session_body_route(
    request: Request, session_id: SessionId, models: ModelsDep, sessions: SessionsDep
) -> BodyAnswer:
    """The body fitted to the session's views (shape and pose together, through their places on the
    template), in the rest pose, with each vertex's uncertainty and the body measurements the views
    support."""
    state = await _session(request, models, sessions, session_id)
    body = await _fit(_measured, models, state)
    return _shaped(session_id, models.version, len(state.views), body)


@router.get(
    ROUTE + "/{session_id}" + IDENTITY,
    response_model=IdentityAnswer,
    responses=PERSON_PROBLEMS | success("session_identity"),
)
async def session_identity_route(
    request: Request,
    session_id: SessionId,
    models: ModelsDep,
    sessions: SessionsDep,
    store: StoreDep,
    top: Annotated[int, Query(ge=1, le=MAX_TOP, description="People to answer.")] = 5,
) -> IdentityAnswer:
    """The stored people nearest the body fitted to the session's views, one answer per person, each
    with a calibrated confidence."""
    state = await _session(request, models, sessions, session_id)
    fitted = await _fit(_fitted, models, state)
    by_shape = await anyio.to_thread.run_sync(shape_ranking, store, models.body, fitted, top)
    common = {"id": session_id, "model_version": models.version, "views": len(state.views)}
    if by_shape is not None:
        people, warnings = answered(by_shape.people, calibrated=True)
        return IdentityAnswer(
            **common, ranked_by="shape", looked_up=None, people=people, warnings=[*warnings, *by_shape.warnings]
        )
    _, spectrum = await solved_body(request, models, fitted.vertices(models.body))
    matches = await anyio.to_thread.run_sync(store.nearest, spectrum, top * SHAPES_PER_PERSON)
    people, warnings = answered_people(matches, top, models.body.identity_scale)
    return IdentityAnswer(
        **common, ranked_by="fitted_body", looked_up=spectrum.tolist(), people=people, warnings=warnings
    )


async def _session(request: Request, models: SpectralModels, sessions: SessionStore, session_id: str) -> SessionState:
    if models.body is None or models.measurer is None:
        raise ProblemError(501, "body-unavailable", "Body fitting unavailable", "these models have no body.npz")
    try:
        return await session_state(sessions, models, session_id, request.app.state.solver.session_union)
    except SessionNotFound:
        raise not_found(session_id) from None


async def _fit(fit: Callable[[SpectralModels, SessionState], T], models: SpectralModels, state: SessionState) -> T:
    """``fit`` run off the event loop; a session it cannot fit a body to (none of its views yet,
    too few points, views no body fits) is a 409."""
    try:
        if not state.views:
            raise NotEnoughSeen("the session has no view yet")
        return await anyio.to_thread.run_sync(fit, models, state)
    except (NotEnoughSeen, NoBodyFits) as exc:
        raise ProblemError(409, "body-not-fitted", "No body fitted to this session", str(exc)) from None


def _fitted(models: SpectralModels, state: SessionState) -> FittedBody:
    return fitted_session(models.body, models.template.vertices, state.views, state.meta.registered)


def _measured(models: SpectralModels, state: SessionState) -> SessionBody:
    coverage = session_coverage(models, state.views)
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
