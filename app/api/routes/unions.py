"""``/v1/union``, ``/v1/localize``, ``/v1/models``: the learned operators on spectra.

Operands are uploaded files and/or spectra (see :mod:`app.api.operands`), in 1/m². A union of
more than two operands is folded left to right, exactly as the operator was trained to chain.
"""

import time
from dataclasses import dataclass
from typing import Annotated, Literal

import anyio
import numpy as np
from fastapi import APIRouter, File, Form, Query, Request, Response, UploadFile
from pydantic import BaseModel, Field

from app.api.deps import SettingsDep
from app.api.examples import success
from app.api.metrics import INFERENCE
from app.api.operands import MAX_OPERANDS, Operand, resolve_operands
from app.api.problems import MODEL_SLUGS, UPLOAD_PROBLEMS, UPLOAD_SLUGS, problem_responses
from app.contract import INTERVAL_Z
from app.core.config import Settings
from app.geometry.plausibility import size_warnings
from app.inference.models import SpectralModels, UnionEstimate
from app.inference.template import PART_NAMES, coloured_template
from app.retrieval.store import StoreUnavailable

router = APIRouter(tags=["unions"])
# What the union-based routes can answer: an upload's problems, and the models'.
UNION_PROBLEMS = problem_responses(*UPLOAD_PROBLEMS, slugs=UPLOAD_SLUGS | MODEL_SLUGS)

FilesField = Annotated[
    list[UploadFile] | None,
    File(max_length=MAX_OPERANDS, description="Partial scans (mesh or point cloud), one operand each."),
]
SpectraField = Annotated[
    str | None,
    Form(description="JSON list of eigenvalue lists (1/m², ascending), e.g. a previous union.", examples=["[[...]]"]),
]
UnitsQuery = Annotated[Literal["m", "cm", "mm"], Query(description="Units of the uploaded files.")]
ScaleQuery = Annotated[float | None, Query(gt=0, description="Factor to metres for the files; overrides units.")]


MODEL_VERSION_FIELD = Field(description="Content hash of the ONNX models: replicas agree iff they serve the same.")


class OperandSpectrum(BaseModel):
    source: str = Field(description="files[i] <name> or spectra[i].")
    eigenvalues: list[float] = Field(description="The operand's own spectrum, 1/m²: send it back as a spectrum.")


class UnionResponse(BaseModel):
    eigenvalues: list[float] = Field(description="Spectrum of the union, 1/m², non-decreasing.")
    sigma: list[float] = Field(description="Per-eigenvalue standard deviation, calibrated on held-out pairs.")
    lower: list[float] = Field(description="Lower end of the 90 % interval.")
    upper: list[float] = Field(description="Upper end of the 90 % interval.")
    operands: list[OperandSpectrum] = Field(description="Each operand's own spectrum, for caching.")
    model_version: str = MODEL_VERSION_FIELD
    solve_ms: float = Field(description="Eigen-solves of the uploaded files.")
    inference_ms: float = Field(description="The union operator's time.")
    warnings: list[str] = Field(
        default_factory=list,
        description="What looks wrong though it was answered: an uploaded shape's implausible area, or "
        "operands more than 10× apart in size (a unit slip?), each naming its operand.",
    )


class LocalizeResponse(UnionResponse):
    vertices: list[int] = Field(description="Template vertices inside the region (or its mirror image).")
    area_fraction: float = Field(description="Share of the template's area covered.")
    part_coverage: dict[str, float] = Field(description="Covered share of each body part's area.")
    template_vertices: int = Field(description="Vertices of the template body the indices refer to.")


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
    database: DatabaseInfo = Field(description="The ShapeDNA database's backend and size.")


def _models(request: Request) -> SpectralModels:
    return request.app.state.resources.require_models()


@dataclass(frozen=True)
class UnionOutcome:
    """The operands of a request, their union and what each step cost."""

    operands: list[Operand]
    result: UnionEstimate
    solve_ms: float
    inference_ms: float
    warnings: list[str]

    def fields(self, models: SpectralModels) -> dict:
        """The response fields every union-based endpoint shares."""
        return {
            "eigenvalues": self.result.eigenvalues.tolist(),
            "sigma": self.result.sigma.tolist(),
            "lower": self.result.lower.tolist(),
            "upper": self.result.upper.tolist(),
            "operands": [OperandSpectrum(source=o.source, eigenvalues=o.eigenvalues) for o in self.operands],
            "model_version": models.version,
            "solve_ms": round(self.solve_ms, 2),
            "inference_ms": round(self.inference_ms, 2),
            "warnings": self.warnings,
        }


async def union_of_operands(
    request: Request,
    settings: Settings,
    files: list[UploadFile] | None,
    spectra: str | None,
    units: Literal["m", "cm", "mm"],
    scale: float | None,
) -> UnionOutcome:
    """Resolve the operands (solving uploaded files) and fold them through the union operator."""
    models = _models(request)
    operands, solve_ms = await resolve_operands(request, settings, files, spectra, models.k, units, scale)
    started = time.perf_counter()
    values = [np.asarray(o.eigenvalues, dtype=np.float64) for o in operands]
    result = await anyio.to_thread.run_sync(models.union, values)
    seconds = time.perf_counter() - started
    INFERENCE.labels("union").observe(seconds)
    warnings = [f"{o.source}: {w}" for o in operands if o.report for w in o.report.warnings]
    warnings += size_warnings(values, [o.source for o in operands])
    return UnionOutcome(operands, result, solve_ms, seconds * 1e3, warnings)


@router.post(
    "/union",
    response_model=UnionResponse,
    responses={**UNION_PROBLEMS, **success("union")},
)
async def union(
    request: Request,
    settings: SettingsDep,
    files: FilesField = None,
    spectra: SpectraField = None,
    units: UnitsQuery = "m",
    scale: ScaleQuery = None,
) -> UnionResponse:
    """Spectrum of the union of partial scans of one body, with a 90 % interval.

    Two or more operands fold left to right, ((A ∪ B) ∪ C) ∪ …; one operand is returned as is
    (σ = 0). The result is exactly the same whichever order two operands come in.
    """
    outcome = await union_of_operands(request, settings, files, spectra, units, scale)
    return UnionResponse(**outcome.fields(_models(request)))


@router.post(
    "/localize",
    response_model=LocalizeResponse,
    responses={
        **UNION_PROBLEMS,
        200: {"content": {"application/ply": {}, **success("localize")[200]["content"]}},
    },
)
async def localize(
    request: Request,
    settings: SettingsDep,
    files: FilesField = None,
    spectra: SpectraField = None,
    units: UnitsQuery = "m",
    scale: ScaleQuery = None,
    format: Annotated[
        Literal["json", "ply"], Query(description="ply: the template mesh with the region as vertex colours.")
    ] = "json",
) -> LocalizeResponse | Response:
    """Where on the template body the union of the operands lies, and how much of each part it covers."""
    models = _models(request)
    outcome = await union_of_operands(request, settings, files, spectra, units, scale)
    started = time.perf_counter()
    region = await anyio.to_thread.run_sync(models.localize, outcome.result.eigenvalues)
    INFERENCE.labels("localizer").observe(time.perf_counter() - started)
    if format == "ply":
        ply = await anyio.to_thread.run_sync(coloured_template, models.template, region.vertices)
        return Response(
            ply, media_type="application/ply", headers={"content-disposition": "inline; filename=region.ply"}
        )
    return LocalizeResponse(
        **outcome.fields(models),
        vertices=region.vertices.tolist(),
        area_fraction=region.area_fraction,
        part_coverage=region.part_coverage,
        template_vertices=len(models.template.vertices),
    )


@router.get(
    "/models",
    response_model=ModelsResponse,
    responses={**problem_responses(503, slugs=MODEL_SLUGS), **success("models")},
)
async def models_info(request: Request) -> ModelsResponse:
    """What is loaded: versions, k, units, the union interval's meaning, the template, the database."""
    models, resources = _models(request), request.app.state.resources
    backend = "postgresql" if resources.settings.database_url else "sqlite"
    try:
        store = await resources.require_store()
        database = DatabaseInfo(backend=backend, shapes=await anyio.to_thread.run_sync(store.count))
    except StoreUnavailable as exc:
        database = DatabaseInfo(backend=backend, shapes=None, problem=str(exc))
    return ModelsResponse(
        model_version=models.version,
        k=models.k,
        units="eigenvalues in 1/m² of shapes in metres",
        interval=f"eigenvalues ± {INTERVAL_Z}·sigma holds 90 % of held-out eigenvalues",
        template_vertices=len(models.template.vertices),
        parts=list(PART_NAMES),
        database=database,
    )
