"""``/v1/retrieve`` and ``/v1/shapes``: the ShapeDNA database of complete shapes.

Reads are open; writes (add, delete) need the ``X-API-Key`` header to match the configured
key, compared in constant time. With no key configured, writes are refused outright.
"""

import hmac
from typing import Annotated

import anyio
import numpy as np
from fastapi import APIRouter, File, Form, Header, Path, Query, Request, Response, UploadFile
from pydantic import BaseModel, Field

from app.api.deps import SettingsDep
from app.api.examples import success
from app.api.operands import solve_upload, upload_options
from app.api.problems import (
    DATABASE_SLUGS,
    MODEL_SLUGS,
    UPLOAD_PROBLEMS,
    UPLOAD_SLUGS,
    ProblemError,
    problem_responses,
)
from app.api.routes.unions import FilesField, ScaleQuery, SpectraField, UnitsQuery, union_of_operands
from app.geometry.errors import InvalidGeometry
from app.geometry.io import resolve_file_type
from app.retrieval.store import ShapeStore

router = APIRouter(tags=["retrieval"])
MAX_TOP = 100
RETRIEVE_RESPONSES = success("retrieve") | problem_responses(
    *UPLOAD_PROBLEMS, slugs=UPLOAD_SLUGS | MODEL_SLUGS | DATABASE_SLUGS
)
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


class ShapePage(BaseModel):
    total: int = Field(description="Shapes stored in all.")
    offset: int = Field(description="Shapes skipped before this page.")
    shapes: list[ShapeOut] = Field(description="This page, oldest first.")


class MatchOut(BaseModel):
    id: str = Field(description="The stored shape's id.")
    label: str = Field(description="Its identity label.")
    distance: float = Field(description="ShapeDNA distance: Euclidean on log λ₂…λ_k.")


class RetrieveResponse(BaseModel):
    query: list[float] = Field(description="The union spectrum that was looked up.")
    matches: list[MatchOut] = Field(description="Nearest first.")
    warnings: list[str] = Field(default_factory=list, description="As in the union's answer (unit slips).")


async def _store(request: Request) -> ShapeStore:
    return await request.app.state.resources.require_store()


def _require_key(settings, given: str | None) -> None:
    expected = settings.api_key.get_secret_value() if settings.api_key else None
    if expected is None:
        raise ProblemError(403, "writes-disabled", "Writes disabled", "no API key is configured on this server")
    if given is None or not hmac.compare_digest(given.encode(), expected.encode()):
        raise ProblemError(401, "invalid-api-key", "Invalid API key", "X-API-Key is missing or wrong")


@router.post(
    "/retrieve",
    response_model=RetrieveResponse,
    responses=RETRIEVE_RESPONSES,
)
async def retrieve(
    request: Request,
    settings: SettingsDep,
    files: FilesField = None,
    spectra: SpectraField = None,
    units: UnitsQuery = "m",
    scale: ScaleQuery = None,
    top: Annotated[int, Query(ge=1, le=MAX_TOP, description="Number of matches.")] = 10,
) -> RetrieveResponse:
    """The stored complete shapes nearest to the union of the operands."""
    outcome = await union_of_operands(request, settings, files, spectra, units, scale)
    matches = await anyio.to_thread.run_sync((await _store(request)).nearest, outcome.result.eigenvalues, top)
    return RetrieveResponse(
        query=outcome.result.eigenvalues.tolist(),
        matches=[MatchOut(id=m.record.id, label=m.record.label, distance=m.distance) for m in matches],
        warnings=outcome.warnings,
    )


@router.post(
    "/shapes",
    response_model=ShapeOut,
    status_code=201,
    responses=ADD_RESPONSES,
)
async def add_shape(
    request: Request,
    settings: SettingsDep,
    file: Annotated[UploadFile, File(description="A complete (closed) shape.")],
    label: Annotated[str, Form(min_length=1, max_length=200, description="Identity label.")],
    units: UnitsQuery = "m",
    scale: ScaleQuery = None,
    x_api_key: Annotated[str | None, Header()] = None,
) -> ShapeOut:
    """Compute a complete shape's spectrum and store it under an identity label."""
    _require_key(settings, x_api_key)
    options = upload_options(settings, request.app.state.resources.require_models().k, units, scale)
    report = await solve_upload(request, await file.read(), resolve_file_type(file.filename, None), options)
    if report.boundary != "none":
        raise InvalidGeometry(
            "the store holds complete shapes, and this one has a boundary (its spectrum is a partial "
            "scan's, Dirichlet): send a closed surface, or unite the parts first"
        )
    record = await anyio.to_thread.run_sync(
        (await _store(request)).add, label, np.asarray(report.eigenvalues), file.filename or "upload"
    )
    return ShapeOut(**record.__dict__)


@router.get(
    "/shapes",
    response_model=ShapePage,
    responses={**problem_responses(422, slugs={"invalid-request"}), **success("list_shapes")},
)
async def list_shapes(
    request: Request,
    offset: Annotated[int, Query(ge=0, le=MAX_OFFSET, description="Shapes to skip.")] = 0,
    limit: Annotated[int, Query(ge=1, le=500)] = 50,
) -> ShapePage:
    """Stored shapes, oldest first, a page at a time."""
    store = await _store(request)
    records = await anyio.to_thread.run_sync(store.page, offset, limit)
    total = await anyio.to_thread.run_sync(store.count)
    return ShapePage(total=total, offset=offset, shapes=[ShapeOut(**r.__dict__) for r in records])


@router.delete(
    "/shapes/{shape_id}",
    status_code=204,
    responses=problem_responses(
        401, 403, 404, 422, slugs={"invalid-api-key", "writes-disabled", "shape-not-found", "invalid-request"}
    ),
)
async def delete_shape(
    request: Request,
    settings: SettingsDep,
    shape_id: Annotated[str, Path(max_length=64)],
    x_api_key: Annotated[str | None, Header()] = None,
) -> Response:
    """Remove a stored shape."""
    _require_key(settings, x_api_key)
    if not await anyio.to_thread.run_sync((await _store(request)).delete, shape_id):
        raise ProblemError(404, "shape-not-found", "Shape not found", f"no shape with id {shape_id}")
    return Response(status_code=204)
