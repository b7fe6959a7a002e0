"""``POST /v1/overlap``: how much registered views overlap, measured from their footprint tokens.

A front-end that posts a scanner's views one by one (``/v1/spectrum?footprint=true``) and then
sends only spectra has no geometry left for ``measure_overlap``. It keeps each view's footprint
token instead and asks here for each union step's overlap and boundary share, which it then
tells the union-based routes (``overlap=``, ``boundary=``). The answer carries the union's own
footprint, so the next view needs only two tokens (the union so far and the view): one request
per view, whatever the session's length.
"""

import time
from typing import Annotated

import anyio
from fastapi import APIRouter, Form
from pydantic import BaseModel, Field

from app.api import form_json
from app.api.examples import success
from app.api.operands import MAX_OPERANDS
from app.api.problems import problem_responses
from app.geometry.overlap import Footprint, footprint_from_token, footprint_token, measured_fold
from app.inference.models import InvalidOverlap

router = APIRouter(tags=["unions"])
ROUTE = "/overlap"


class OverlapResponse(BaseModel):
    overlaps: list[float] = Field(
        description="Each union step's overlap (share of the smaller operand inside the other), one per token "
        "after the first: send them as the union routes' overlap, in the same order."
    )
    boundaries: list[float] = Field(
        description="Each union step's boundary share (how much of the two operands' boundary length is left on "
        "the union's boundary: 0 closed, 1 neither covers any of the other's), one per token after the first: "
        "send them as the union routes' boundary, beside overlap."
    )
    union_footprint: str = Field(
        description="The footprint token of the union of all the views: send it first next time, with the "
        "new view's token, instead of every earlier one."
    )
    measure_ms: float = Field(description="Time spent measuring.")


# A form with no upload and no model: what its body and its field can raise.
OVERLAP_PROBLEMS = problem_responses(
    400, 408, 413, 422, slugs={"invalid-form", "body-timeout", "upload-too-large", "invalid-overlap", "invalid-request"}
)


@router.post(ROUTE, response_model=OverlapResponse, responses={**OVERLAP_PROBLEMS, **success("overlap")})
async def overlap(
    footprints: Annotated[
        str,
        Form(
            description="JSON list of footprint tokens (from /v1/spectrum?footprint=true, or a previous answer's "
            "union_footprint), in the order the views are united. The views must be of one body in one "
            "coordinate frame and one pose (a scanner's registered views).",
            examples=['["fp1.AAAA…", "fp1.BBBB…"]'],
        ),
    ],
) -> OverlapResponse:
    """The overlap and boundary share of each step of the left fold ((A ∪ B) ∪ C) ∪ … of registered views."""
    views = parse_footprints(footprints)
    started = time.perf_counter()
    fold = await anyio.to_thread.run_sync(measured_fold, views)  # k-d trees: off the event loop
    token = await anyio.to_thread.run_sync(footprint_token, fold.union)
    measure_ms = (time.perf_counter() - started) * 1e3
    return OverlapResponse(
        overlaps=fold.overlaps, boundaries=fold.boundaries, union_footprint=token, measure_ms=round(measure_ms, 2)
    )


def parse_footprints(text: str) -> list[Footprint]:
    """The ``footprints`` field as footprints (1 to MAX_OPERANDS), or 422 naming the bad token."""
    tokens = form_json.loads(text, "footprints", InvalidOverlap)
    if not isinstance(tokens, list) or not tokens or not all(isinstance(t, str) for t in tokens):
        raise InvalidOverlap("footprints must be a non-empty JSON list of footprint tokens (strings)")
    if len(tokens) > MAX_OPERANDS:
        raise InvalidOverlap(f"at most {MAX_OPERANDS} footprints, got {len(tokens)}")
    views = []
    for index, token in enumerate(tokens):
        try:
            views.append(footprint_from_token(token))
        except ValueError as exc:
            raise InvalidOverlap(f"footprints[{index}] {exc}") from None
    return views
