"""``/v1/shapes``: the ShapeDNA database of complete shapes, listed, added and deleted.

Reads are open; writes (add, delete) need the ``X-API-Key`` header (:data:`app.api.deps.WriteKeyDep`).
"""

from typing import Annotated

import anyio
import numpy as np
from fastapi import APIRouter, File, Form, Path, Query, Request, Response, UploadFile
from pydantic import BaseModel, Field

from app.api.deps import ModelsDep, SettingsDep, StoreDep, WriteKeyDep
from app.api.examples import success
from app.api.operands import CapHolesQuery, ScaleQuery, UnitsQuery, solve_upload, upload_options
from app.api.problems import DATABASE_SLUGS, UPLOAD_PROBLEMS, UPLOAD_SLUGS, ProblemError, problem_responses
from app.api.solver import SolverPool
from app.geometry.errors import InvalidGeometry
from app.geometry.formats import listed
from app.geometry.io import resolve_file_type
from app.geometry.pipeline import SpectrumOptions, SpectrumReport
from app.geometry.plausibility import ImplausibleSize
from app.inference.models import SpectralModels
from app.retrieval.store import StoredBody
from app.sessions.body import stored_body

router = APIRouter(tags=["retrieval"])
ADD_RESPONSES = success("add_shape", 201) | problem_responses(
    401,
    403,
    *UPLOAD_PROBLEMS,
    slugs=UPLOAD_SLUGS | DATABASE_SLUGS | {"invalid-api-key", "writes-disabled", "models-unavailable"},
)
MAX_OFFSET = 2**31  # far past any store; beyond, SQLite's integer binding would overflow


class ShapeOut(BaseModel):
    id: str = Field(description="The stored shape's id (for DELETE /v1/shapes/{id}).")
    label: str = Field(description="Identity label.")
    source: str = Field(description="seed (the benchmark's complete shapes) or the uploaded file name.")
    spectrum: list[float] = Field(description="Its plain (closed-surface) spectrum, 1/m².")
    created_at: str = Field(description="When it was stored, ISO 8601 in UTC.")


class AddedShape(ShapeOut):
    body_fitted: bool = Field(
        description="Whether a body was fitted to the scan and stored with it: identity (GET /v1/sessions/{id}/"
        "identity) ranks stored people by their bodies' shape. False where the models have no body basis or "
        "correspondence model, or no body fits the scan (not a person, or a size no person has)."
    )


class ShapePage(BaseModel):
    total: int = Field(description="Shapes stored in all.")
    offset: int = Field(description="Shapes skipped before this page.")
    shapes: list[ShapeOut] = Field(description="This page, oldest first.")


@router.post(
    "/shapes",
    response_model=AddedShape,
    status_code=201,
    responses=ADD_RESPONSES,
    dependencies=[WriteKeyDep],
)
async def add_shape(
    request: Request,
    settings: SettingsDep,
    models: ModelsDep,
    store: StoreDep,
    file: Annotated[UploadFile, File(description="A complete (closed) shape: " + listed())],
    label: Annotated[str, Form(min_length=1, max_length=200, description="Identity label.")],
    units: UnitsQuery = "m",
    scale: ScaleQuery = None,
    cap_holes: CapHolesQuery = False,
) -> AddedShape:
    """Compute a complete shape's spectrum and store it under an identity label, with the body
    fitted to it where one fits (its shape coefficients, what identity ranks people by)."""
    options = upload_options(settings, models.k, units, scale, cap_holes=cap_holes)
    data, file_type = await file.read(), resolve_file_type(file.filename, None)
    report, body = await _solved_with_body(request, models, data, file_type, options)
    if report.boundary != "none":
        raise InvalidGeometry(
            "the store holds complete shapes, and this one has a boundary (its spectrum is a partial "
            "scan's, Dirichlet): send a closed surface, a whole-body scan with cap_holes=true to cap its "
            "blind spots, or unite the parts first"
        )
    spectrum = np.asarray(report.eigenvalues)
    record = await anyio.to_thread.run_sync(store.add, label, spectrum, file.filename or "upload", body)
    return AddedShape(**record.__dict__, body_fitted=body is not None)


async def _solved_with_body(
    request: Request, models: SpectralModels, data: bytes, file_type: str, options: SpectrumOptions
) -> tuple[SpectrumReport, StoredBody | None]:
    """The shape's spectrum and, where the models can place and fit it, its body. A shape of a
    size no person has is stored by its spectrum alone (the store holds any closed shape)."""
    if models.body is None or models.correspondence is None:
        return await solve_upload(request, data, file_type, options), None
    solver: SolverPool = request.app.state.solver
    try:
        solved = await solver.solve_with_functions(
            data, file_type, options, vectors=False, place_with=models.correspondence.path
        )
    except ImplausibleSize:
        return await solve_upload(request, data, file_type, options), None
    if solved.report.boundary != "none":  # refused by the caller: not fitted for nothing
        return solved.report, None
    body = await anyio.to_thread.run_sync(
        stored_body, models.body, models.template.vertices, models.correspondence, solved.part, solved.places
    )
    return solved.report, body


@router.get(
    "/shapes",
    response_model=ShapePage,
    responses={**problem_responses(422, slugs={"invalid-request"}), **success("list_shapes")},
)
async def list_shapes(
    store: StoreDep,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET, description="Shapes to skip.")] = 0,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
) -> ShapePage:
    """Stored shapes, oldest first, a page at a time."""
    records = await anyio.to_thread.run_sync(store.page, offset, limit)
    total = await anyio.to_thread.run_sync(store.count)
    return ShapePage(total=total, offset=offset, shapes=[ShapeOut(**r.__dict__) for r in records])


@router.delete(
    "/shapes/{shape_id}",
    status_code=204,
    dependencies=[WriteKeyDep],
    responses=problem_responses(
        401, 403, 404, 422, slugs={"invalid-api-key", "writes-disabled", "shape-not-found", "invalid-request"}
    ),
)
async def delete_shape(
    store: StoreDep,
    shape_id: Annotated[str, Path(max_length=64)],
) -> Response:
    """Remove a stored shape."""
    if not await anyio.to_thread.run_sync(store.delete, shape_id):
        raise ProblemError(404, "shape-not-found", "Shape not found", f"no shape with id {shape_id}")
    return Response(status_code=204)
