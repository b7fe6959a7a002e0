"""``POST /v1/spectrum``: the truncated Laplace–Beltrami spectrum of an uploaded shape."""

from dataclasses import asdict, dataclass
from typing import Annotated, Literal

import anyio
from fastapi import APIRouter, File, Form, Query, Request, Response, UploadFile
from pydantic import Field

from app.api.deps import SettingsDep
from app.api.examples import success
from app.api.operands import CapHolesQuery, solve_upload, upload_options
from app.api.problems import UPLOAD_PROBLEMS, UPLOAD_SLUGS, problem_responses
from app.api.responses import NPZ_MEDIA_TYPE
from app.core.errors import InputError
from app.geometry.formats import listed
from app.geometry.io import resolve_file_type
from app.geometry.overlap import footprint_token
from app.geometry.pipeline import SpectrumReport
from app.geometry.spectrum import DEFAULT_K, MAX_K

router = APIRouter(tags=["spectra"])


@dataclass(frozen=True, kw_only=True)
class FootprintedReport(SpectrumReport):
    """The report, and where the shape lies (asked with ``footprint=true``)."""

    footprint: Annotated[
        str,
        Field(
            description="The shape's footprint token: its surface as 4 096 points at most, in metres, for "
            "POST /v1/overlap to measure how much registered views overlap without uploading them again."
        ),
    ]


@router.post(
    "/spectrum",
    response_model=SpectrumReport | FootprintedReport,
    responses={
        **problem_responses(*UPLOAD_PROBLEMS, slugs=UPLOAD_SLUGS),
        200: {"content": {NPZ_MEDIA_TYPE: {}, **success("spectrum")[200]["content"]}},
    },
)
async def spectrum(
    request: Request,
    settings: SettingsDep,
    file: Annotated[UploadFile, File(description="Mesh or point cloud: " + listed())],
    k: Annotated[int, Query(ge=1, le=MAX_K, description="Number of eigenvalues.")] = DEFAULT_K,
    units: Annotated[Literal["m", "cm", "mm"], Query(description="Units of the file.")] = "m",
    scale: Annotated[float | None, Query(gt=0, description="Factor to metres; overrides units.")] = None,
    closed: Annotated[bool, Query(description="Point clouds only: the cloud is a closed surface.")] = False,
    cap_holes: CapHolesQuery = False,
    file_type: Annotated[str | None, Query(description="Overrides the upload's extension.")] = None,
    boundary: Annotated[str | None, Form(description="Point clouds: JSON list of boundary point indices.")] = None,
    vectors: Annotated[
        bool,
        Query(
            description="Also the eigenfunctions: the answer is then an .npz of NPY arrays eigenvalues (k,), "
            "eigenfunctions (vertices, k; M-orthonormal, 0 on Dirichlet vertices), vertex_indices (vertices,; "
            "each solved vertex's index in the uploaded file, -1 for a filled pin-hole's centre) and report "
            "(this JSON answer, as a string). At most 5 000 000 values (vertices × k)."
        ),
    ] = False,
    footprint: Annotated[
        bool,
        Query(
            description="Also the shape's footprint token (see POST /v1/overlap): for a scanner's registered "
            "views, whose overlaps are then measured from the tokens. Not with vectors."
        ),
    ] = False,
) -> SpectrumReport | FootprintedReport | Response:
    """First k Dirichlet (or, for a closed surface, plain) Laplace–Beltrami eigenvalues in 1/m²."""
    resolved_type = resolve_file_type(file.filename, file_type)
    data = await file.read()
    options = upload_options(settings, k, units, scale, closed=closed, boundary=boundary, cap_holes=cap_holes)
    if footprint and vectors:
        raise InputError("footprint and vectors cannot be asked together")
    if footprint:
        solved = await request.app.state.solver.solve_with_functions(
            data, resolved_type, options, vectors=False, footprint=True
        )
        token = await anyio.to_thread.run_sync(footprint_token, solved.footprint)
        return FootprintedReport(**asdict(solved.report), footprint=token)
    if not vectors:
        return await solve_upload(request, data, resolved_type, options)
    solved = await request.app.state.solver.solve_with_functions(data, resolved_type, options)
    return Response(
        solved.npz(),
        media_type=NPZ_MEDIA_TYPE,
        headers={"content-disposition": "attachment; filename=eigenfunctions.npz"},
    )
