"""``POST /v1/localize``: where on the template body the union of the operands lies."""

import time
from typing import Annotated, Literal

import anyio
import numpy as np
from fastapi import APIRouter, Query, Response
from pydantic import Field

from app.api.deps import region_tokens
from app.api.examples import success
from app.api.metrics import INFERENCE
from app.api.responses import UNION_PROBLEMS, DetailQuery, UnionResponse, shaped
from app.api.unions import UnionDep
from app.inference.cover import united
from app.inference.template import coloured_template

router = APIRouter(tags=["unions"])


class LocalizeResponse(UnionResponse):
    vertices: list[int] = Field(description="Template vertices inside the region (or its mirror image).")
    area_fraction: float = Field(description="Share of the template's area covered.")
    part_coverage: dict[str, float] = Field(description="Covered share of each body part's area.")
    template_vertices: int = Field(description="Vertices of the template body the indices refer to.")
    located_by: Literal["correspondence", "spectrum"] = Field(
        description="correspondence: every operand placed on the template (an uploaded file by the correspondence "
        "model, a spectrum by the region sent with it), the region the union of their regions, on the side "
        "scanned; spectrum: the localizer's reading of the union's spectrum (up to left/right)."
    )
    vertex_confidence: list[float] | None = Field(
        None,
        description="With correspondence and every operand an uploaded file: per vertex of vertices, the "
        "confidence of the nearest placed part vertex (the probability of the template patch it was placed in).",
    )
    region_token: str | None = Field(
        None,
        description="With correspondence: the region and its covered shares as a token to send back in regions "
        "beside its union's spectrum (the next step of a session), so the next union is localized, its overlap "
        "measured and its coverage read on the template.",
    )


@router.post(
    "/localize",
    response_model=LocalizeResponse,
    responses={
        **UNION_PROBLEMS,
        200: {"content": {"application/ply": {}, **success("localize")[200]["content"]}},
    },
)
async def localize(
    union: UnionDep,
    format: Annotated[
        Literal["json", "ply"], Query(description="ply: the template mesh with the region as vertex colours.")
    ] = "json",
    detail: DetailQuery = "full",
) -> LocalizeResponse | Response:
    """Where on the template body the union of the operands lies, and how much of each part it
    covers: for uploaded parts, the union of the regions their vertices are placed on (the
    correspondence model); for spectra, the localizer's region of the union, as large as its
    probabilities expect, grown to hold each operand's own region."""
    models = union.models
    outcome = await union.solved(locate=True)
    confidence = token = None
    if outcome.covers is not None:
        union_cover = united(outcome.covers)
        token = (await region_tokens(union.request)).issue(union_cover, np.asarray(outcome.result.eigenvalues))
        count = len(outcome.covers)
        region, confidence = await anyio.to_thread.run_sync(models.placed_region, union_cover, outcome.placed, count)
    else:
        started = time.perf_counter()
        # A union holds each of its operands' own regions; one operand is its own union.
        parts = [np.asarray(o.eigenvalues) for o in outcome.operands] if len(outcome.operands) > 1 else []
        region = await anyio.to_thread.run_sync(models.localize, outcome.result.eigenvalues, parts)
        INFERENCE.labels("localizer").observe(time.perf_counter() - started)
    if format == "ply":
        ply = await anyio.to_thread.run_sync(coloured_template, models.template, region.vertices)
        return Response(
            ply, media_type="application/ply", headers={"content-disposition": "inline; filename=region.ply"}
        )
    answer = LocalizeResponse(
        **outcome.fields(models),
        vertices=region.vertices.tolist(),
        area_fraction=region.area_fraction,
        part_coverage=region.part_coverage,
        template_vertices=len(models.template.vertices),
        located_by="spectrum" if outcome.covers is None else "correspondence",
        region_token=token,
        vertex_confidence=None if confidence is None else np.round(confidence, 3).tolist(),
    )
    return shaped(answer, detail, {"vertices": True, "vertex_confidence": True})
