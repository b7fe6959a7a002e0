"""``GET /v1/models``: what is served — the models' version, k, units, the interval, the
template and the ShapeDNA database."""

from typing import Literal

import anyio
from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from app.api.deps import ModelsDep
from app.api.examples import success
from app.api.problems import MODEL_SLUGS, problem_responses
from app.api.responses import MODEL_VERSION_FIELD
from app.contract import INTERVAL_Z
from app.inference.template import PART_NAMES
from app.retrieval.store import StoreUnavailable

router = APIRouter(tags=["unions"])


class DatabaseInfo(BaseModel):
    backend: Literal["sqlite", "postgresql"] = Field(description="Which store holds the ShapeDNA database.")
    shapes: int | None = Field(description="Complete shapes stored for retrieval; null while the database is down.")
    problem: str | None = Field(None, description="Why the database cannot be used, when it cannot.")


class ModelsResponse(BaseModel):
    model_version: str = MODEL_VERSION_FIELD
    k: int = Field(description="Eigenvalues per spectrum the models take and give.")
    units: str = Field(description="What the eigenvalues are measured in.")
    interval: str = Field(description="What lower and upper mean.")
    template_vertices: int = Field(description="Vertices of the template body.")
    parts: list[str] = Field(description="The body parts coverage is reported for, in order.")
    told: list[str] = Field(
        description="What the union operator reads besides the operands' spectra where a caller tells it (the "
        "union routes' query parameters of these names): overlap, boundary; empty when it reads neither."
    )
    correspondence: bool = Field(
        description="Whether uploaded parts are placed on the template (POST /v1/correspondence; regions and "
        "overlaps of uploads measured on the template)."
    )
    body: bool = Field(
        description="Whether a body is fitted to what was scanned (GET /v1/sessions/{id}/body and /identity; "
        "/v1/reconstruct and /v1/retrieve of uploads through the fitted body)."
    )
    database: DatabaseInfo = Field(description="The ShapeDNA database's backend and size.")


@router.get(
    "/models",
    response_model=ModelsResponse,
    responses={**problem_responses(503, slugs=MODEL_SLUGS), **success("models")},
)
async def models_info(request: Request, models: ModelsDep) -> ModelsResponse:
    """What is loaded: versions, k, units, the union interval's meaning, the template, the database."""
    resources = request.app.state.resources
    backend = "postgresql" if resources.settings.database_url else "sqlite"
    try:
        store = await resources.require_store()
        database = DatabaseInfo(backend=backend, shapes=await anyio.to_thread.run_sync(store.count))
    except StoreUnavailable as exc:  # the models are served whether the database is up or not
        database = DatabaseInfo(backend=backend, shapes=None, problem=str(exc))
    return ModelsResponse(
        model_version=models.version,
        k=models.k,
        units="eigenvalues in 1/m² of shapes in metres",
        interval=f"eigenvalues ± {INTERVAL_Z}·sigma holds 90 % of held-out eigenvalues",
        template_vertices=len(models.template.vertices),
        parts=list(PART_NAMES),
        told=[name for name, read in (("overlap", models.reads_overlap), ("boundary", models.reads_boundary)) if read],
        correspondence=models.correspondence is not None,
        body=models.body is not None,
        database=database,
    )
