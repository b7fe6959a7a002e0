"""``POST /v1/retrieve``: the stored complete shapes nearest to the union of the operands.

The store holds complete shapes' closed spectra (ShapeDNA). An open surface — a whole body
scanned with its soles or the top of its head unseen, or scans that leave a part out — has a
boundary, and its spectrum is of another kind (λ₁ > 0, every eigenvalue raised): ranked as it
is, the nearest stored shapes are the smallest bodies, whoever was scanned. Where every operand
is an upload placed on the template, such a union, and any union of several uploads, is ranked
by shape: the stored people's shape coefficients against those of the body fitted to the
uploads' points, under what the uploads left unseen (:func:`app.sessions.identity.shape_ranking`,
as a session's identity is ranked; ``benchmarks.body_from_parts``); else through the body the
shape decoder rebuilds from it, whose own closed spectrum is comparable
(``benchmarks.retrieval_open_surfaces`` measures how much more often the right person comes
first). That costs a solve, so the route is admitted like an upload
(``app.main``). A whole-body scan uploaded as a mesh does better still with ``cap_holes=true``:
its blind spots capped, it is a closed surface and ranked as one.

Two operands whose overlap is not told leave their union uncertain mostly through that one
number: a closed union of two is ranked by its **share profile**, each stored shape at its
distance to the nearest of the unions told each share of ``PROFILE_SHARES``, i.e. under the
overlap that explains that shape best: the right person comes first more often than under the
operator's own guess of the share, nearly as often as told the true one
(``benchmarks.retrieval_open_surfaces``, its table in ``benchmarks/RESULTS.md``).
"""

from typing import Annotated, Literal

import anyio
import numpy as np
from fastapi import APIRouter, Query, Request
from pydantic import BaseModel, Field

from app.api.deps import StoreDep
from app.api.examples import success
from app.api.operands import CapHolesQuery
from app.api.problems import DATABASE_SLUGS, MODEL_SLUGS, UPLOAD_PROBLEMS, UPLOAD_SLUGS, problem_responses
from app.api.rebuilt import RebuiltBody, UploadsFit, fit_uploads, scanned_body
from app.api.responses import PersonAnswer, answered, answered_people
from app.api.unions import UnionDep, UnionOutcome
from app.contract import PROFILE_SHARES
from app.inference.body import open_surface
from app.inference.models import SpectralModels
from app.retrieval.store import Match, ShapeStore
from app.sessions.identity import SHAPES_PER_PERSON, ShapeRanking, shape_ranking

router = APIRouter(tags=["retrieval"])
ROUTE = "/retrieve"  # an open surface's query solves the body rebuilt from it: admitted like an upload (app.main)
MAX_TOP = 100
RankedBy = Literal["union", "shape", "fitted_body", "rebuilt_body", "share_profile"]
RETRIEVE_RESPONSES = success("retrieve") | problem_responses(
    *UPLOAD_PROBLEMS, slugs=UPLOAD_SLUGS | MODEL_SLUGS | DATABASE_SLUGS
)


class MatchOut(BaseModel):
    id: str = Field(description="The stored shape's id.")
    label: str = Field(description="Its identity label.")
    distance: float = Field(
        description="ShapeDNA distance (Euclidean on log λ₂…λ_k) from the spectrum ranked; ranked by shape, the "
        "Mahalanobis distance of the shape's body from the fitted body's, under the fit's uncertainty."
    )
    share: float | None = Field(
        default=None,
        description="Ranked by share profile: the overlap share (of the smaller operand inside the other) under "
        "which the union comes nearest to this shape; null otherwise.",
    )


class RetrieveResponse(BaseModel):
    query: list[float] = Field(description="The union spectrum of the operands, 1/m².")
    ranked_by: RankedBy = Field(
        description="union: the query itself was ranked (a closed surface, or rebuild=false); shape: every "
        "operand an upload, the query an open surface or a union of several: the stored shapes that have a body "
        "ranked by their person's shape coefficients against the body fitted to the uploads' points (decisions "
        "039, 049); fitted_body: the same where no stored shape has a body, ranked by that body's closed "
        "spectrum; rebuilt_body: the "
        "query is an open surface (λ₁ > 1 % of λ₂), ranked through the body the shape decoder rebuilds from it; "
        "share_profile: two operands whose overlap was not told, a closed union, each stored shape ranked by the "
        "union told the share that brings it nearest (each match's share)."
    )
    looked_up: list[float] | None = Field(
        description="The spectrum ranked against the stored shapes: the query's, the fitted or rebuilt body's own, "
        "or by share profile the union told the first match's share; null when ranked by shape."
    )
    matches: list[MatchOut] = Field(description="Nearest first: stored shapes, several poses of one person each.")
    people: list[PersonAnswer] = Field(
        description="The same ranking, one answer per person (label) at their nearest stored shape, nearest first."
    )
    warnings: list[str] = Field(
        default_factory=list,
        description="As in the union's answer (unit slips), and what ranking an open surface means.",
    )


SHAPE_NOTE = (
    "ranked by shape: each stored person's shape against the body fitted to the uploads' points, what they left "
    "unseen counting against no one (the model card's bodies table)"
)
FITTED_NOTE = (
    "the query is an open surface (λ₁ > 0), ranked through the body fitted to the uploads' points, whose closed "
    "spectrum compares with the stored shapes' (5-view anny sessions: the model card's bodies table)"
)


def open_surface_warning(rebuild: bool, body: RebuiltBody | None) -> str:
    """What ranking an open surface's query means, for the way it was ranked."""
    if body is None:
        why = "as asked (rebuild=false)" if not rebuild else "since these models have no shape decoder"
        return (
            f"the query is an open surface (λ₁ > 0: holes, or parts of the body unseen), ranked by its own spectrum "
            f"{why}: the stored shapes are closed, and the nearest to an open surface's spectrum are the smallest "
            "bodies, whoever was scanned (benchmarks/RESULTS.md: retrieval_open_surfaces)"
        )
    if body.verdict == "unseen":
        return (
            f"the query is an open surface that leaves a large part of the body unseen (the body rebuilt from it "
            f"comes back {100 * body.gap:.0f} % from its spectrum): the matches are the stored shapes nearest that "
            "body, not an identification (partial unions seldom find the right person first, either way)"
        )
    return (
        "the query is an open surface (λ₁ > 0: holes such as the soles or the top of the head), ranked through the "
        "body the shape decoder rebuilds from it, whose closed spectrum compares with the stored shapes' (more "
        "often right than its own spectrum, less than a whole-body scan sent with cap_holes=true: "
        "benchmarks/RESULTS.md, retrieval_open_surfaces)"
    )


def profiled(outcome: UnionOutcome, models: SpectralModels, profile: bool) -> bool:
    """Whether the union is ranked by its share profile: asked for, two operands, no overlap told
    or measured, a graph that reads one, and a closed union (an open one goes through its rebuilt
    body, and the store holds closed shapes)."""
    untold = not outcome.overlaps and models.reads_overlap
    return profile and untold and len(outcome.operands) == 2 and not open_surface(outcome.result.eigenvalues)


async def looked_up_spectra(
    request: Request, models: SpectralModels, outcome: UnionOutcome, rebuild: bool, profile: bool, fit: UploadsFit
) -> tuple[np.ndarray, RankedBy, list[str]]:
    """The spectrum, or (m, k) spectra, to rank, how they were chosen (an open union through
    ``fit``'s body where one was fitted to the uploads), and the warnings that go with them."""
    union = outcome.result
    if profiled(outcome, models, profile):
        a, b = (np.asarray(o.eigenvalues, dtype=np.float64) for o in outcome.operands)
        return await anyio.to_thread.run_sync(models.union_profile, a, b), "share_profile", []
    if not open_surface(union.eigenvalues):
        return union.eigenvalues, "union", []
    if not rebuild or models.decoder_session is None:
        return union.eigenvalues, "union", [open_surface_warning(rebuild, None)]
    body = await scanned_body(request, models, outcome, fit)
    if body.by == "fitted":
        return body.eigenvalues, "fitted_body", [FITTED_NOTE]
    return body.eigenvalues, "rebuilt_body", [open_surface_warning(rebuild, body)]


def by_shape(outcome: UnionOutcome, ranking: ShapeRanking) -> RetrieveResponse:
    """The answer ranked by shape: its shapes, its people with their calibrated confidences."""
    people, ahead = answered(ranking.people, calibrated=True)
    return RetrieveResponse(
        query=outcome.result.eigenvalues.tolist(),
        ranked_by="shape",
        looked_up=None,
        matches=[MatchOut(id=id_, label=label, distance=distance) for id_, label, distance in ranking.shapes],
        people=people,
        warnings=[*outcome.warnings, SHAPE_NOTE, *ahead, *ranking.warnings],
    )


def match_out(match: Match, ranked_by: RankedBy) -> MatchOut:
    share = float(PROFILE_SHARES[match.query]) if ranked_by == "share_profile" else None
    return MatchOut(id=match.record.id, label=match.record.label, distance=match.distance, share=share)


async def ranked(
    store: ShapeStore, looked_up: np.ndarray, ranked_by: RankedBy, top: int, scale: float | None
) -> tuple[list[MatchOut], list[PersonAnswer], list[str], np.ndarray]:
    """The ``top`` matches, the ``top`` people (confidences with ``scale``, where calibrated for this
    ranking) and whether the first is clearly ahead, and the spectrum the first match was found by."""
    matches = await anyio.to_thread.run_sync(store.nearest, looked_up, top * SHAPES_PER_PERSON)
    first = np.atleast_2d(looked_up)[matches[0].query] if matches else np.atleast_2d(looked_up)[0]
    people, ahead = answered_people(matches, top, scale)
    return [match_out(m, ranked_by) for m in matches[:top]], people, ahead, first


@router.post(
    ROUTE,
    response_model=RetrieveResponse,
    responses=RETRIEVE_RESPONSES,
)
async def retrieve(
    union: UnionDep,
    store: StoreDep,
    top: Annotated[int, Query(ge=1, le=MAX_TOP, description="Number of matches.")] = 10,
    rebuild: Annotated[
        bool,
        Query(
            description="Rank an open surface (λ₁ > 0: a scan with holes), or a union of several uploads, by the "
            "body fitted to the uploads or the shape decoder rebuilds from the union; false ranks the union's own "
            "spectrum as given."
        ),
    ] = True,
    cap_holes: CapHolesQuery = False,
    profile: Annotated[
        bool,
        Query(
            description="Two operands whose overlap is not told (no overlap, no measure_overlap): rank each stored "
            "shape under the share that brings the union nearest to it; false ranks the untold union itself."
        ),
    ] = True,
) -> RetrieveResponse:
    """The stored complete shapes nearest to the union of the operands (an open one by the shape of the body
    fitted to the uploads, or through its rebuilt body; two operands whose overlap is not told by their share
    profile)."""
    models = union.models
    # An open query, or a union glued from several uploads (whose person the fitted body finds
    # first more often than the glued union's spectrum does: decision 049), is ranked by the body
    # fitted to where its uploads lie; one closed scan, or one capped, by its own spectrum.
    outcome = await union.solved(cap_holes=cap_holes, locate=models.body is not None and not cap_holes)
    fit = UploadsFit()
    if rebuild and (open_surface(outcome.result.eigenvalues) or len(outcome.operands) > 1):
        fit = await anyio.to_thread.run_sync(fit_uploads, models, outcome)
    if fit.fitted is not None:
        ranking = await anyio.to_thread.run_sync(shape_ranking, store, models.body, fit.fitted, top)
        if ranking is not None:
            return by_shape(outcome, ranking)
    looked_up, ranked_by, notes = await looked_up_spectra(union.request, models, outcome, rebuild, profile, fit)
    scale = models.body.identity_scale if ranked_by == "fitted_body" and models.body is not None else None
    matches, people, ahead, first = await ranked(store, looked_up, ranked_by, top, scale)
    return RetrieveResponse(
        query=outcome.result.eigenvalues.tolist(),
        ranked_by=ranked_by,
        looked_up=first.tolist(),
        matches=matches,
        people=people,
        warnings=[*outcome.warnings, *notes, *ahead],
    )
