"""``/v1/union``, ``/v1/localize``, ``/v1/models``: the learned operators on spectra.

Spectra come from ``/v1/spectrum`` (or a previous union) in 1/m², k of them. A union of more
than two operands is folded left to right, exactly as the operator was trained to chain.
"""

from typing import Annotated

import anyio
from fastapi import APIRouter, Request
from pydantic import BaseModel, Field

from app.api.problems import problem_responses
from app.inference.models import INTERVAL_Z, SpectralModels
from app.inference.spectra import checked_spectrum
from app.inference.template import PART_NAMES

MAX_OPERANDS = 32

router = APIRouter(tags=["unions"])
Spectrum = Annotated[list[float], Field(description="Eigenvalues in 1/m², ascending.")]


class UnionRequest(BaseModel):
    spectra: list[Spectrum] = Field(min_length=2, max_length=MAX_OPERANDS, description="Two or more operands.")


class UnionResponse(BaseModel):
    eigenvalues: list[float] = Field(description="Predicted spectrum of the union, 1/m², non-decreasing.")
    sigma: list[float] = Field(description="Per-eigenvalue standard deviation, calibrated on held-out data.")
    lower: list[float] = Field(description="Lower end of the 90 % interval.")
    upper: list[float] = Field(description="Upper end of the 90 % interval.")
    operands: int


class LocalizeRequest(BaseModel):
    spectrum: Spectrum


class LocalizeResponse(BaseModel):
    vertices: list[int] = Field(description="Template vertices inside the region (or its mirror image).")
    area_fraction: float = Field(description="Share of the template's area covered.")
    part_coverage: dict[str, float] = Field(description="Covered share of each body part's area.")
    template_vertices: int


class ModelsResponse(BaseModel):
    k: int
    units: str
    interval: str
    template_vertices: int
    parts: list[str]


def _models(request: Request) -> SpectralModels:
    return request.app.state.models


@router.post("/union", response_model=UnionResponse, responses=problem_responses(422))
async def union(request: Request, body: UnionRequest) -> UnionResponse:
    """The spectrum of the union of partial shapes of one body, with a 90 % interval."""
    models = _models(request)
    spectra = [checked_spectrum(s, models.k, f"spectra[{i}]") for i, s in enumerate(body.spectra)]
    result = await anyio.to_thread.run_sync(models.union, spectra)
    return UnionResponse(
        eigenvalues=result.eigenvalues.tolist(),
        sigma=result.sigma.tolist(),
        lower=result.lower.tolist(),
        upper=result.upper.tolist(),
        operands=len(spectra),
    )


@router.post("/localize", response_model=LocalizeResponse, responses=problem_responses(422))
async def localize(request: Request, body: LocalizeRequest) -> LocalizeResponse:
    """Where on the template body the region with this spectrum lies."""
    models = _models(request)
    region = await anyio.to_thread.run_sync(models.localize, checked_spectrum(body.spectrum, models.k))
    return LocalizeResponse(
        vertices=region.vertices.tolist(),
        area_fraction=region.area_fraction,
        part_coverage=region.part_coverage,
        template_vertices=len(models.template.vertices),
    )


@router.get("/models", response_model=ModelsResponse)
async def models_info(request: Request) -> ModelsResponse:
    """What is loaded: k, units, the interval the union's sigma is calibrated for, the template."""
    models = _models(request)
    return ModelsResponse(
        k=models.k,
        units="eigenvalues in 1/m² of shapes in metres",
        interval=f"eigenvalues ± {INTERVAL_Z}·sigma holds 90 % of held-out eigenvalues",
        template_vertices=len(models.template.vertices),
        parts=list(PART_NAMES),
    )
