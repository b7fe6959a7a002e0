"""The body the shape decoder rebuilds from a union, its own spectrum and what the round trip says.

``/v1/reconstruct`` returns that body; ``/v1/retrieve`` ranks an open surface through its closed
spectrum. The loop is closed on the spectrum: the rebuilt body goes through the same solver
workers as an upload, so both routes are admitted like uploads (``app.main``).
"""

import time
from dataclasses import dataclass, replace
from typing import Literal

import anyio
import numpy as np
import trimesh
from fastapi import Request

from app.api.metrics import INFERENCE
from app.api.solver import SolverPool
from app.api.unions import UnionOutcome
from app.geometry.pipeline import SpectrumOptions
from app.inference.body import open_surface, spectrum_gap
from app.inference.bodyfit import FittedBody, NotEnoughSeen
from app.inference.models import SpectralModels, UnionEstimate
from app.sessions.body import NoBodyFits, calibrated_sigma, fitted_views
from app.sessions.fused import view_of_part

# The rebuilt body's spectrum comes back within a few per cent of a complete body's or a two-part
# union's, and far from a union of scans that leave part of the body unseen (the model card's
# reconstruction section).
GAP_WARNING = 0.10
# An open surface (λ₁ > 0) never comes back as the closed body's spectrum: complete scans with
# blind spots come back tens of per cent away and still decode to a body near the truth, a
# session's views that miss a quarter of the body much farther (the card's blind_spots and
# session_spectrum rows): the warning sits between the two.
OPEN_GAP_WARNING = 0.60
# A predicted union (σ > 0) that is open is no measured scan with blind spots: the operator's
# unions of two parts covering the body come back nearer than its unions of parts that leave a
# tenth or more of the body out (the card's reconstruction section, Test A). Over this the union
# leaves part of the body unseen.
PREDICTED_OPEN_GAP_WARNING = 0.25

RoundTrip = Literal["closed", "open", "unseen", "fitted"]  # fitted: no round trip, the body fits the uploads' points
BodyBy = Literal["fitted", "decoded"]


def round_trip(gap: float, union: UnionEstimate) -> RoundTrip:
    """What the round trip says of the rebuilt body: ``closed``, the union's spectrum came back;
    ``open``, an open surface's (λ₁ > 0) came back as a complete scan with blind spots does;
    ``unseen``, the gap says a large part of the body is not in the union: not to be trusted.
    An open union the operator predicted (σ > 0) is judged by its own, tighter threshold."""
    is_open = bool(open_surface(union.eigenvalues))
    predicted = bool(np.any(union.sigma > 0))
    threshold = (PREDICTED_OPEN_GAP_WARNING if predicted else OPEN_GAP_WARNING) if is_open else GAP_WARNING
    if gap > threshold:
        return "unseen"
    return "open" if is_open and gap > GAP_WARNING else "closed"


@dataclass(frozen=True)
class RebuiltBody:
    """A rebuilt body: rest-pose vertices (m, template order), its PLY, its own spectrum (1/m²), the
    mean relative gap of λ₂…λ_k to the union's, the round trip's verdict, how it was made, each
    vertex's σ (m, a fitted body's), and why it was not fitted where it could have been."""

    vertices: np.ndarray
    mesh: bytes
    eigenvalues: np.ndarray
    gap: float
    verdict: RoundTrip
    by: BodyBy = "decoded"
    sigma: np.ndarray | None = None
    not_fitted: str | None = None


def body_mesh(models: SpectralModels, vertices: np.ndarray) -> bytes:
    """Binary PLY of a rebuilt body (the template's faces)."""
    return trimesh.Trimesh(vertices, models.template.faces, process=False).export(file_type="ply")


async def rebuilt_body(request: Request, models: SpectralModels, union: UnionEstimate) -> RebuiltBody:
    """Decode ``union`` (with its σ, which picks the decoder's network) and solve the body's
    spectrum on the solver pool. The models must have a decoder (``models.decoder_session``)."""
    started = time.perf_counter()
    vertices = await anyio.to_thread.run_sync(models.reconstruct, union.eigenvalues, union.sigma)
    INFERENCE.labels("decoder").observe(time.perf_counter() - started)
    mesh, eigenvalues = await solved_body(request, models, vertices)
    gap = spectrum_gap(eigenvalues, union.eigenvalues)
    return RebuiltBody(vertices, mesh, eigenvalues, gap, round_trip(gap, union))


@dataclass(frozen=True)
class UploadsFit:
    """The body fitted to the operands' points (``fitted``), or why none fits them where every
    operand is an upload placed on the template (``not_fitted``); both None where one is not."""

    fitted: FittedBody | None = None
    not_fitted: str | None = None


def fit_uploads(models: SpectralModels, outcome: UnionOutcome) -> UploadsFit:
    """The body fitted to the uploads' points through their places, in frames and poses of their
    own (decision 039: nearer the person than their union's spectrum decoded), where every
    operand is an upload placed on the template and the models have a body. Blocking: a few
    seconds of one core at most (it reads at most ``FIT_POINTS`` points)."""
    parts = [operand.part for operand in outcome.operands]
    every_upload_placed = all(part is not None for part in parts) and len(outcome.placed) == len(parts)
    if models.body is None or not every_upload_placed:
        return UploadsFit()
    geometry = [view_of_part(part) for part in parts if part is not None]
    places = [placed.placement.position for placed in outcome.placed]
    try:
        return UploadsFit(fitted_views(models.body, models.template.vertices, geometry, places, False))
    except (NotEnoughSeen, NoBodyFits) as exc:
        return UploadsFit(not_fitted=str(exc))


async def scanned_body(request: Request, models: SpectralModels, outcome: UnionOutcome, fit: UploadsFit) -> RebuiltBody:
    """The body of the person the operands were scanned from: ``fit``'s body where one was fitted
    to the uploads, else decoded from the union (the models must then have a decoder; where a
    fit was tried, the body says why it failed)."""
    if fit.fitted is None:
        decoded = await rebuilt_body(request, models, outcome.result)
        return replace(decoded, not_fitted=fit.not_fitted)
    vertices = fit.fitted.vertices(models.body)
    mesh, eigenvalues = await solved_body(request, models, vertices)
    gap = spectrum_gap(eigenvalues, outcome.result.eigenvalues)
    sigma = calibrated_sigma(models.body, fit.fitted, len(outcome.operands))
    return RebuiltBody(vertices, mesh, eigenvalues, gap, "fitted", "fitted", sigma)


async def solved_body(request: Request, models: SpectralModels, vertices: np.ndarray) -> tuple[bytes, np.ndarray]:
    """A body's PLY and its own spectrum, solved on the solver pool."""
    mesh = await anyio.to_thread.run_sync(body_mesh, models, vertices)
    solver: SolverPool = request.app.state.solver
    report = await solver.solve(mesh, "ply", SpectrumOptions(k=models.k))
    return mesh, np.asarray(report.eigenvalues, dtype=np.float64)
