"""``POST /v1/union``: the spectrum of the union of partial scans.

Operands are uploaded files and/or spectra (see :mod:`app.api.operands`), in 1/m². A union of
more than two operands is folded left to right, exactly as the operator was trained to chain.
"""

from fastapi import APIRouter

from app.api.examples import success
from app.api.responses import UNION_PROBLEMS, UnionResponse
from app.api.unions import UnionDep

router = APIRouter(tags=["unions"])


@router.post(
    "/union",
    response_model=UnionResponse,
    responses={**UNION_PROBLEMS, **success("union")},
)
async def union(union: UnionDep) -> UnionResponse:
    """Spectrum of the union of partial scans of one body, with a 90 % interval.

    Two or more operands fold left to right, ((A ∪ B) ∪ C) ∪ …; one operand is returned as is
    (σ = 0). The result is exactly the same whichever order two operands come in.
    """
    outcome = await union.solved()
    return UnionResponse(**outcome.fields(union.models))
