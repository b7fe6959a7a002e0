"""``POST /v1/retrieve``: the stored complete shapes nearest to the union of the operands."""

from typing import Annotated

import anyio
from fastapi import APIRouter, Query, Request
from pydantic import BaseModel, Field

from app.api.deps import ModelsDep, SettingsDep, StoreDep
from app.api.examples import success
from app.api.operands import FilesField, MeasureOverlapQuery, OverlapQuery, ScaleQuery, SpectraField, UnitsQuery
from app.api.problems import DATABASE_SLUGS, MODEL_SLUGS, UPLOAD_PROBLEMS, UPLOAD_SLUGS, problem_responses
from app.api.unions import union_of_operands

router = APIRouter(tags=["retrieval"])
MAX_TOP = 100
RETRIEVE_RESPONSES = success("retrieve") | problem_responses(
    *UPLOAD_PROBLEMS, slugs=UPLOAD_SLUGS | MODEL_SLUGS | DATABASE_SLUGS
)


class MatchOut(BaseModel):
    id: str = Field(description="The stored shape's id.")
    label: str = Field(description="Its identity label.")
    distance: float = Field(description="ShapeDNA distance: Euclidean on log λ₂…λ_k.")


class RetrieveResponse(BaseModel):
    query: list[float] = Field(description="The union spectrum that was looked up.")
    matches: list[MatchOut] = Field(description="Nearest first.")
    warnings: list[str] = Field(default_factory=list, description="As in the union's answer (unit slips).")


@router.post(
    "/retrieve",
    response_model=RetrieveResponse,
    responses=RETRIEVE_RESPONSES,
)
async def retrieve(
    request: Request,
    settings: SettingsDep,
    models: ModelsDep,
    store: StoreDep,
    files: FilesField = None,
    spectra: SpectraField = None,
    units: UnitsQuery = "m",
    scale: ScaleQuery = None,
    overlap: OverlapQuery = None,
    measure_overlap: MeasureOverlapQuery = False,
    top: Annotated[int, Query(ge=1, le=MAX_TOP, description="Number of matches.")] = 10,
) -> RetrieveResponse:
    """The stored complete shapes nearest to the union of the operands."""
    outcome = await union_of_operands(request, settings, models, files, spectra, units, scale, overlap, measure_overlap)
    matches = await anyio.to_thread.run_sync(store.nearest, outcome.result.eigenvalues, top)
    return RetrieveResponse(
        query=outcome.result.eigenvalues.tolist(),
        matches=[MatchOut(id=m.record.id, label=m.record.label, distance=m.distance) for m in matches],
        warnings=outcome.warnings,
    )
