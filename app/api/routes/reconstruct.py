"""``POST /v1/reconstruct``: the scanned person's body, fitted to the uploads or rebuilt from the union's spectrum.

Where every operand is an uploaded file placed on the template, the body is fitted to the
uploads' points (:func:`app.api.rebuilt.scanned_body`, ``body_by: fitted``): shape and each
upload's pose together, far closer than any spectrum gets (decision 039). Otherwise:

The union of the operands (as ``/v1/union`` computes it) is read as a complete body's spectrum
and decoded to that body in the rest pose, on the template's topology (the decoder in
``models/reconstruction.onnx``: a linear shape basis and two networks, see the model card). The
union's σ goes with it: one operand of a closed surface is a measured complete body (σ = 0),
read by the network trained on such spectra; a union of several is a prediction, and one operand
with a boundary (a partial scan, or a whole-body scan with blind spots: λ₁ > 0) no complete
body, and both are read by the network that learned the operator's error, partial unions and
blind spots (the graph routes each row itself). A whole body uploaded as one scan with
``cap_holes=true`` has its holes capped first and is read as the closed body it was (unknown
people's scans with blind spots come back about half as far off: ``benchmarks.decoder_blind_spots``). The
loop is closed on the spectrum: the rebuilt body goes through the same solver workers as an
upload, and its own spectrum comes back beside the one it was decoded from, so a client sees
how far to trust it. A union of parts that do not cover the body is decoded all the same (the
network's best guess of the person); the gap between the two spectra shows it.
"""

from typing import Annotated, Literal

import anyio
import numpy as np
from fastapi import APIRouter, Query, Response
from pydantic import Field

from app.api.examples import success
from app.api.operands import CapHolesQuery
from app.api.problems import ProblemError, problem_responses
from app.api.rebuilt import BodyBy, RoundTrip, fit_uploads, scanned_body
from app.api.responses import UNION_PROBLEMS, UnionResponse
from app.api.unions import UnionDep
from app.inference.body import body_height, surface_area

router = APIRouter(tags=["unions"])
ROUTE = "/reconstruct"  # every request solves the body it rebuilt: admitted like an upload (app.main)
VERTEX_DECIMALS = 5  # 10 µm: far below the decoder's error, and it keeps the JSON small


class ReconstructResponse(UnionResponse):
    body_by: BodyBy = Field(
        description="fitted: the body fitted to the uploads' points through their places on the template, shape "
        "and each upload's pose together (every operand an upload, and a body fits them; decision 039); decoded: "
        "the union's spectrum decoded by the shape decoder (spectra operands, or no body fitted: the warnings say "
        "why)."
    )
    height_m: float = Field(description="The rebuilt body's height (extent along the template's up axis, z).")
    area_m2: float = Field(description="The rebuilt body's surface area.")
    vertices: list[list[float]] = Field(
        description="The rebuilt body's vertices in the rest pose, metres, in the template's vertex order "
        "(its faces are the template's: ask for format=ply for the mesh)."
    )
    sigma_m: list[float] | None = Field(
        description="A fitted body: each vertex's uncertainty (m), the less the uploads saw the larger, scaled so "
        "that 90 % of vertices lie within 1.645 σ of the truth on anny sessions; null for a decoded body."
    )
    body_eigenvalues: list[float] = Field(
        description="The rebuilt body's own spectrum, 1/m², by the same engine as /v1/spectrum."
    )
    spectrum_relative_error: float = Field(
        description="Mean relative difference of λ₂…λ_k between the rebuilt body's spectrum and the union's "
        "(λ₁ of a closed body is 0): the decoder's own check (its figures on complete bodies and two-part "
        "unions: the model card); over 10 % adds a warning. An open surface's spectrum (λ₁ > 0: a scan with holes) "
        "cannot come back as a closed body's: up to 60 % it adds a note, over 60 % the warning (a large part of "
        "the body unseen); for an open union the operator predicted (several operands) the warning comes over 25 % "
        "(where these thresholds fall among complete scans with blind spots and unions that cover the body or "
        "not: docs/api.md, the rebuilt body)."
    )


def round_trip_warnings(verdict: RoundTrip, gap: float) -> list[str]:
    """The response's words for a round trip's verdict."""
    if verdict == "unseen":
        return [
            f"the rebuilt body's spectrum is {100 * gap:.0f} % from the union's: the union is not a complete "
            "body's spectrum (do the scans cover the whole body?), so the body is not to be trusted"
        ]
    if verdict == "open":
        return [
            f"the union's spectrum is an open surface's (λ₁ > 0: holes such as the soles, or a small part "
            f"unseen): the body is rebuilt closed, so its spectrum is {100 * gap:.0f} % from the union's, as a "
            "complete scan with blind spots comes back (the model card says how far such scans decode)"
        ]
    return []


@router.post(
    ROUTE,
    response_model=ReconstructResponse,
    responses={
        **UNION_PROBLEMS,
        **problem_responses(501),
        200: {"content": {"application/ply": {}, **success("reconstruct")[200]["content"]}},
    },
)
async def reconstruct(
    union: UnionDep,
    cap_holes: CapHolesQuery = False,
    format: Annotated[
        Literal["json", "ply"],
        Query(
            description="ply: the rebuilt body as a mesh (height, area, the spectrum gap and the round trip's "
            "verdict — closed, open or unseen, as the warnings say — in X- headers)."
        ),
    ] = "json",
) -> ReconstructResponse | Response:
    """The complete body of the person the operands were scanned from, in the rest pose, up to pose."""
    models = union.models
    if models.decoder_session is None:
        raise ProblemError(
            501, "reconstruction-unavailable", "Reconstruction unavailable", "these models have no shape decoder"
        )
    outcome = await union.solved(cap_holes=cap_holes, locate=models.body is not None)
    fit = await anyio.to_thread.run_sync(fit_uploads, models, outcome)
    body = await scanned_body(union.request, models, outcome, fit)
    height, area = body_height(body.vertices), surface_area(body.vertices, models.template.faces)
    warnings = [*outcome.warnings, *round_trip_warnings(body.verdict, body.gap)]
    if body.not_fitted is not None:
        warnings.append(f"no body was fitted to the uploads ({body.not_fitted}): the union's spectrum was decoded")
    if format == "ply":
        headers = {
            "content-disposition": "inline; filename=body.ply",
            "x-height-m": f"{height:.4f}",
            "x-area-m2": f"{area:.4f}",
            "x-spectrum-relative-error": f"{body.gap:.4f}",
            "x-round-trip": body.verdict,
            "x-body-by": body.by,
        }
        return Response(body.mesh, media_type="application/ply", headers=headers)
    return ReconstructResponse(
        **(outcome.fields(models) | {"warnings": warnings}),
        body_by=body.by,
        height_m=height,
        area_m2=area,
        vertices=np.round(body.vertices, VERTEX_DECIMALS).tolist(),
        sigma_m=None if body.sigma is None else np.round(body.sigma, VERTEX_DECIMALS).tolist(),
        body_eigenvalues=body.eigenvalues.tolist(),
        spectrum_relative_error=body.gap,
    )
