"""``POST /v1/correspondence``: where on the template body each vertex of one uploaded part lies."""

import io
from typing import Annotated, Literal

import anyio
import numpy as np
import trimesh
from fastapi import APIRouter, File, Form, Query, Request, Response, UploadFile
from pydantic import BaseModel, Field

from app.api.deps import ModelsDep, SettingsDep, TokensDep
from app.api.examples import success
from app.api.metrics import INFERENCE
from app.api.operands import ScaleQuery, UnitsQuery, upload_options
from app.api.problems import MODEL_SLUGS, UPLOAD_PROBLEMS, UPLOAD_SLUGS, ProblemError, problem_responses
from app.api.responses import MODEL_VERSION_FIELD, NPZ_MEDIA_TYPE, DetailQuery, shaped
from app.geometry.formats import listed
from app.geometry.io import resolve_file_type
from app.geometry.pipeline import Solved
from app.inference.correspondence import Placement
from app.inference.models import SpectralModels

router = APIRouter(tags=["correspondence"])
ROUTE = "/correspondence"
POSITION_DECIMALS = 4  # 0.1 mm: far below the model's error, and it keeps the JSON small
CONFIDENCE_DECIMALS = 3


PlacesKind = Literal["network", "relaxed"]


class CorrespondenceRegion(BaseModel):
    vertices: list[int] = Field(description="Template vertices the part covers: where its placed area lies dense.")
    area_fraction: float = Field(description="Share of the template's area covered.")
    part_coverage: dict[str, float] = Field(
        description="Covered share of each body part's area, summed from how much of the template around each "
        "vertex the part's placed area fills (the gaps between a ragged view's strips do not count)."
    )
    token: str | None = Field(
        description="The region and its covered shares as a token: send it in regions beside this part's "
        "spectrum, so later unions and localizations place the part, and read its coverage, without uploading it "
        "again. Null, with a warning saying why, where the part's places are doubted (its region left empty): a "
        "token would tell later unions a region nobody knows."
    )


# What detail=coverage leaves out: every per-vertex array.
PER_VERTEX = {
    "vertex_indices": True,
    "template_vertex": True,
    "position": True,
    "confidence": True,
    "region": {"vertices"},
}


class CorrespondenceResponse(BaseModel):
    model_version: str = MODEL_VERSION_FIELD
    eigenvalues: list[float] = Field(
        description="The part's spectrum from the same solve (as /v1/spectrum answers it, k of the models): send it "
        "as a spectra operand with region.token in regions."
    )
    vertices: int = Field(description="Vertices (or points) placed: the upload's, after the service's cleaning.")
    placed_on: int = Field(
        description="Vertices the correspondence graph read: the part's own, or, for a mesh above the service's "
        "placed_vertices, its quadric-collapsed copy's; each vertex then has the place and confidence of the copy "
        "vertex it collapsed into, so neighbouring vertices may share one."
    )
    vertex_indices: list[int] = Field(
        description="Each placed vertex's index in the uploaded file (-1 for the centre of a filled pin-hole)."
    )
    template_vertex: list[int] = Field(description="Each placed vertex's nearest template vertex.")
    places: PlacesKind = Field(
        description="How the places were found: the network's, or relaxed toward the part's edge lengths."
    )
    position: list[list[float]] = Field(description="Each placed vertex's place on the template's rest pose, metres.")
    confidence: list[float] = Field(
        description="Each placed vertex's confidence: the probability of the template patch it was placed in."
    )
    mean_confidence: float = Field(description="Area-weighted mean confidence over the part.")
    magnification: float = Field(
        description="How many times larger the correspondence network read the part, the size it placed it surest "
        "at: about the template body's size over the person's (1 for an adult's part; about 1.3-1.8 for a child's, "
        "whose parts the network, trained on adults, places 10-40 cm off as sent)."
    )
    region: CorrespondenceRegion = Field(description="The template region the part covers.")
    template_vertices: int = Field(description="Vertices of the template body the indices refer to.")
    warnings: list[str] = Field(
        description="What looks wrong though it was placed: an implausible area (units?), or places too "
        "uncertain to trust its region and coverage (not a body part, or a view the model cannot place)."
    )


@router.post(
    ROUTE,
    response_model=CorrespondenceResponse,
    responses={
        **problem_responses(*UPLOAD_PROBLEMS, 501, slugs=UPLOAD_SLUGS | MODEL_SLUGS | {"correspondence-unavailable"}),
        200: {"content": {NPZ_MEDIA_TYPE: {}, "application/ply": {}, **success("correspondence")[200]["content"]}},
    },
)
async def correspondence(
    request: Request,
    settings: SettingsDep,
    models: ModelsDep,
    tokens: TokensDep,
    file: Annotated[UploadFile, File(description="Mesh or point cloud: " + listed())],
    units: UnitsQuery = "m",
    scale: ScaleQuery = None,
    closed: Annotated[bool, Query(description="Point clouds only: the cloud is a closed surface.")] = False,
    file_type: Annotated[str | None, Query(description="Overrides the upload's extension.")] = None,
    boundary: Annotated[str | None, Form(description="Point clouds: JSON list of boundary point indices.")] = None,
    places: Annotated[
        PlacesKind,
        Query(
            description="relaxed: the network's places relaxed toward the part's own edge lengths, then everything "
            "else read from them: closer to the true places on held-out anny parts, the region about the "
            "network's (the model card's correspondence table), at some cost (docs/api.md)."
        ),
    ] = "network",
    format: Annotated[
        Literal["json", "npz", "ply"],
        Query(
            description="npz: NPY arrays position, confidence, template_vertex, vertex_indices, placed_on, places "
            "and region; ply: the part as the service read it, each vertex coloured by its template place (x, y, z "
            "→ red, green, blue)."
        ),
    ] = "json",
    detail: DetailQuery = "full",
) -> CorrespondenceResponse | Response:
    """Each vertex of one partial scan placed on the template body's rest pose, whatever its pose,
    frame or meshing, with a confidence, and the template region the part covers."""
    if models.correspondence is None:
        raise ProblemError(
            501,
            "correspondence-unavailable",
            "Correspondence unavailable",
            "these models have no correspondence model",
        )
    resolved_type = resolve_file_type(file.filename, file_type)
    data = await file.read()
    options = upload_options(settings, models.k, units, scale, closed=closed, boundary=boundary)
    solved: Solved = await request.app.state.solver.solve_with_functions(
        data, resolved_type, options, vectors=False, place_with=models.correspondence.path, relaxed=places == "relaxed"
    )
    INFERENCE.labels("correspondence").observe(solved.places.graph_ms / 1e3)
    placed = await anyio.to_thread.run_sync(models.correspondence.placed, solved.part, solved.places)
    placement, cover = placed.placement, placed.counted  # a doubted part's region counts nothing
    region = cover.region
    if format == "npz":
        return Response(
            _npz(solved, placement, region, places),
            media_type=NPZ_MEDIA_TYPE,
            headers={"content-disposition": "attachment; filename=correspondence.npz"},
        )
    if format == "ply":
        ply = await anyio.to_thread.run_sync(_coloured_part, models, solved, placement)
        return Response(
            ply, media_type="application/ply", headers={"content-disposition": "inline; filename=correspondence.ply"}
        )
    covered = models.region_of(region, cover.share)
    answer = CorrespondenceResponse(
        model_version=models.version,
        eigenvalues=solved.report.eigenvalues,
        vertices=len(placement.vertex),
        placed_on=solved.part.inputs.vertices,
        vertex_indices=solved.sources.tolist(),
        template_vertex=placement.vertex.tolist(),
        places=places,
        position=np.round(placement.position, POSITION_DECIMALS).tolist(),
        confidence=np.round(placement.confidence, CONFIDENCE_DECIMALS).tolist(),
        mean_confidence=placement.mean_confidence,
        magnification=round(placement.magnification, 4),
        region=CorrespondenceRegion(
            vertices=covered.vertices.tolist(),
            area_fraction=covered.area_fraction,
            part_coverage=covered.part_coverage,
            token=tokens.issue(cover, np.asarray(solved.report.eigenvalues)) if placed.trusted else None,
        ),
        template_vertices=len(models.template.vertices),
        warnings=solved.report.warnings + list(placed.doubts),
    )
    return shaped(answer, detail, PER_VERTEX)


def _npz(solved: Solved, placement: Placement, region: np.ndarray, places: PlacesKind) -> bytes:
    buffer = io.BytesIO()
    np.savez(
        buffer,
        position=placement.position,
        confidence=placement.confidence,
        template_vertex=placement.vertex,
        vertex_indices=solved.sources,
        placed_on=np.array(solved.part.inputs.vertices),
        places=np.array(places),
        region=np.flatnonzero(region),
    )
    return buffer.getvalue()


def _coloured_part(models: SpectralModels, solved: Solved, placement: Placement) -> bytes:
    """Binary PLY of the part as read (mesh or points), coloured by its template place scaled
    to the template's bounding box."""
    low, high = models.template.vertices.min(axis=0), models.template.vertices.max(axis=0)
    colour = np.clip((placement.position - low) / (high - low), 0, 1)
    rgba = np.column_stack([np.round(255 * colour), np.full(len(colour), 255)]).astype(np.uint8)
    part = solved.part
    if part.faces is None:
        return trimesh.PointCloud(part.points, colors=rgba).export(file_type="ply")
    mesh = trimesh.Trimesh(part.points, part.faces, vertex_colors=rgba, process=False)
    return mesh.export(file_type="ply")
