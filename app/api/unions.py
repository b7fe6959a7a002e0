"""The union of a request's operands, shared by every endpoint that reads one (union, localize,
reconstruct, retrieve): operands counted, then resolved (uploads solved), folded through the union
operator, timed, and the warnings collected. Each of those routes takes one parameter for it
(:data:`UnionDep`). No response shaping here: the routes do that.
"""

import time
from dataclasses import dataclass
from typing import Annotated

import anyio
import numpy as np
from fastapi import Depends, Request

from app.api import form_json
from app.api.deps import ModelsDep, SettingsDep, ToldDep, region_tokens
from app.api.metrics import INFERENCE
from app.api.operands import (
    NOT_TOLD,
    Operand,
    OperandsDep,
    SentOperands,
    Told,
    Wanted,
    counted_operands,
    parse_shares,
    parse_spectra,
    resolve_operands,
)
from app.core.config import Settings
from app.geometry.overlap import MeasuredFold, measured_fold
from app.geometry.plausibility import size_warnings
from app.inference.correspondence import PlacedPart
from app.inference.cover import Cover, InvalidRegion
from app.inference.models import (
    InvalidOverlap,
    SpectralModels,
    UnionEstimate,
    checked_boundaries,
    checked_overlaps,
    require_overlap_reader,
)
from app.inference.region_tokens import RegionTokens
from app.sessions.chain import FoldedUnion, Located, OverlapSource, folded_union
from app.sessions.reading import views_union
from app.sessions.session import SessionUnion, placed_view


@dataclass(frozen=True)
class UnionOutcome:
    """The operands of a request, their union and what each step cost."""

    operands: list[Operand]
    result: UnionEstimate
    solve_ms: float
    inference_ms: float
    warnings: list[str]
    overlaps: list[float]  # each union step's overlap as told or measured; empty when neither
    boundaries: list[float]  # each step's boundary share as told or measured; empty when neither
    overlaps_from: OverlapSource | None  # where they came from
    overlaps_told: list[bool]  # per step, whether the union operator was told it
    overlaps_nested: list[bool]  # per step, whether it was told nested (overlap 1) instead of its measured overlap
    placed: list[PlacedPart]  # each uploaded operand placed on the template, when the correspondence model was run
    covers: list[Cover] | None  # what each operand covers on the template (placed or carried), when every one has one
    union_by: str  # what made it: "operand", "learned-chain", or the uploads' geometry (app.sessions.session.UnionBy)

    def fields(self, models: SpectralModels) -> dict:
        """The response fields every union-based endpoint shares."""
        return {
            "eigenvalues": self.result.eigenvalues.tolist(),
            "sigma": self.result.sigma.tolist(),
            "lower": self.result.lower.tolist(),
            "upper": self.result.upper.tolist(),
            "operands": [{"source": o.source, "eigenvalues": o.eigenvalues} for o in self.operands],
            "union_by": self.union_by,
            "model_version": models.version,
            "solve_ms": round(self.solve_ms, 2),
            "inference_ms": round(self.inference_ms, 2),
            "warnings": self.warnings,
            "overlaps": self.overlaps,
            "boundaries": self.boundaries,
            "overlaps_from": self.overlaps_from,
            "overlaps_told": self.overlaps_told,
            "overlaps_nested": self.overlaps_nested,
        }


async def union_of_operands(
    request: Request,
    settings: Settings,
    models: SpectralModels,
    sent: SentOperands,
    told: Told = NOT_TOLD,
    *,
    cap_holes: bool = False,
    locate: bool = False,
) -> UnionOutcome:
    """Resolve the operands (solving uploaded files) and read their union: where every operand
    is an upload and no overlap is told, from the uploads' geometry as a session reads its views
    (:func:`app.sessions.reading.views_union`: fused where ``told.measure`` declares them in one
    frame and pose, else aligned through their places); otherwise the union operator folded over
    their spectra, told the overlap (and boundary share) of each step where the client knows it,
    or measured from the uploads (``told.measure``), or from where the correspondence model places
    them (every operand an upload or a spectrum with its region);
    ``cap_holes``: one uploaded whole-body scan, its holes capped
    (:func:`app.api.operands.resolve_operands`); ``locate``: the route answers the operands'
    region, so even one upload is placed (others place uploads only to measure a step)."""
    overlaps, boundaries = parse_shares(told.overlap), parse_shares(told.boundary, "boundary")
    if told.measure:
        _check_measurable(overlaps, boundaries, sent.spectra, models)
    carried = await _carried(request, told, sent, models)
    place_with = _placing_with(models, sent, carried, locate)
    wanted = Wanted(footprints=told.measure, cap_holes=cap_holes, place_with=place_with)
    counted = await counted_operands(request, sent, models.k, cap_holes)
    checked_overlaps(overlaps, counted.count, models.reads_overlap)
    checked_boundaries(boundaries, overlaps, counted.count, models.reads_boundary)
    operands, solve_ms = await resolve_operands(request, settings, counted, models.k, wanted)
    placed = await anyio.to_thread.run_sync(_placed, models, operands) if place_with else []
    covers = [part.counted for part in placed] + (carried or [])
    if len(covers) != len(operands):
        covers = None  # some operand's place is unknown: the spectral localizer and no measured overlap
    values = [np.asarray(o.eigenvalues, dtype=np.float64) for o in operands]
    started = time.perf_counter()
    read = None
    if overlaps is None and boundaries is None and len(placed) == len(operands) > 1:  # every operand an upload
        read = await _from_geometry(request, models, operands, placed, told.measure)
    if read is None:
        located = None if covers is None else _located(models, placed, carried or [])
        fold = await _folded(models, operands, values, located, overlaps, boundaries, told.measure)
        read = fold, "operand" if len(operands) == 1 else "learned-chain"
    fold, by = read
    seconds = time.perf_counter() - started
    INFERENCE.labels("union").observe(seconds)
    return UnionOutcome(
        operands,
        fold.result,
        solve_ms,
        seconds * 1e3,
        _warnings(operands, placed, values),
        fold.overlaps,
        fold.boundaries,
        fold.source,
        fold.told,
        fold.nested,
        placed,
        covers,
        by,
    )


async def _carried(request: Request, told: Told, sent: SentOperands, models: SpectralModels) -> list[Cover] | None:
    """The regions carried by the spectra operands' tokens (None when none were sent), checked
    against their spectra before anything is solved."""
    tokens = await region_tokens(request) if told.regions is not None else None
    carried = _carried_regions(told.regions, sent.spectra, models, tokens)
    if carried is not None and sent.files and models.correspondence is None:
        raise InvalidRegion("these models cannot place uploaded files: send regions with spectra operands only")
    return carried


def _placing_with(models: SpectralModels, sent: SentOperands, carried: list[Cover] | None, locate: bool) -> str | None:
    """The correspondence graph the uploads are placed with, or None: placed where the route
    answers their region (``locate``) or where there is a union step to measure, and every
    operand can be placed (an upload, or a spectrum whose region was carried)."""
    if models.correspondence is None or not sent.files:
        return None
    steps = len(sent.files) + (len(carried) if carried else 0) > 1
    only_placeable = not (sent.spectra and sent.spectra.strip()) or carried is not None
    return models.correspondence.path if only_placeable and (locate or steps) else None


async def _from_geometry(
    request: Request, models: SpectralModels, operands: list[Operand], placed: list[PlacedPart], measure: bool
) -> tuple[FoldedUnion, str] | None:
    """The uploads' union read from their geometry as a session reads its views (fused where
    ``measure`` declares them in one frame and pose, else aligned through their places), and
    what made it; None where the learned chain reads it (:func:`app.sessions.reading.views_union`)."""
    views = [placed_view(o.source, o.eigenvalues, o.part, part) for o, part in zip(operands, placed, strict=True)]
    union = await views_union(models, views, measure, request.app.state.solver.session_union)
    if union is None:
        return None
    measured = await _measured(operands) if measure else None
    return _as_folded(union, measured), union.union_by


def _warnings(operands: list[Operand], placed: list[PlacedPart], values: list[np.ndarray]) -> list[str]:
    """Every operand's own warnings, each placed upload's doubts, and the sizes that do not fit one body."""
    warnings = [f"{o.source}: {w}" for o in operands if o.report for w in o.report.warnings]
    return warnings + _doubts(operands, placed) + size_warnings(values, [o.source for o in operands])


async def _folded(
    models: SpectralModels,
    operands: list[Operand],
    values: list[np.ndarray],
    located: list[Located] | None,
    overlaps: list[float] | None,
    boundaries: list[float] | None,
    measure: bool,
) -> FoldedUnion:
    """The learned operator folded over the operands' spectra (``values``): told what the client
    told, what the registered uploads' footprints measure, or where ``located`` puts them."""
    source: OverlapSource | None = "told" if overlaps is not None else None
    if measure:
        fold = await _measured(operands)
        overlaps, boundaries = fold.overlaps, fold.boundaries if models.reads_boundary else None
        source = "footprints"
    return await anyio.to_thread.run_sync(folded_union, models, values, located, overlaps, boundaries, source)


async def _measured(operands: list[Operand]) -> MeasuredFold:
    """Each step's overlap and boundary share measured from the registered uploads' footprints
    (k-d trees of up to UNION_POINTS points per step: off the event loop)."""
    footprints = [o.footprint for o in operands if o.footprint is not None]
    return await anyio.to_thread.run_sync(measured_fold, footprints)


def _as_folded(union: SessionUnion, measured: MeasuredFold | None) -> FoldedUnion:
    """A union read from the uploads' geometry in the fields a fold answers: its steps where a
    few uploads that did not align were chained onto the others' union; fused, what the uploads'
    footprints measure (``measured``), told to no operator."""
    if measured is not None and not union.overlaps:
        untold = [False] * len(measured.overlaps)
        return FoldedUnion(union.estimate, measured.overlaps, measured.boundaries, "footprints", untold, untold)
    source = "correspondence" if union.overlaps else None
    nested = list(union.estimate.nested)
    return FoldedUnion(union.estimate, union.overlaps, union.boundaries, source, union.overlaps_told, nested)


def _located(models: SpectralModels, placed: list[PlacedPart], carried: list[Cover]) -> list[Located]:
    """Every operand's place: the uploads' as placed here, then the carried regions'."""
    return [Located.placed(part) for part in placed] + [Located.carried(c, models.vertex_area) for c in carried]


def _placed(models: SpectralModels, operands: list[Operand]) -> list[PlacedPart]:
    """Every uploaded operand placed on the template: the graph ran in the solver worker that
    solved it (its time observed here), its places become a region here; spectra operands have
    nothing to place (their regions, if any, were carried)."""
    placed = []
    for operand in _uploads(operands):
        if operand.places is not None:
            INFERENCE.labels("correspondence").observe(operand.places.graph_ms / 1e3)
        placed.append(models.correspondence.placed(operand.part, operand.places))
    return placed


def _uploads(operands: list[Operand]) -> list[Operand]:
    """The operands with a part to place (uploaded files), in order."""
    return [operand for operand in operands if operand.part is not None]


def _doubts(operands: list[Operand], placed: list[PlacedPart]) -> list[str]:
    """A warning for each placed upload whose places cannot be trusted (left out of its region)."""
    if not placed:
        return []
    return [
        f"{operand.source}: {warning}"
        for operand, part in zip(_uploads(operands), placed, strict=True)
        for warning in part.doubts
    ]


def _carried_regions(
    text: str | None, spectra: str | None, models: SpectralModels, signer: RegionTokens | None
) -> list[Cover] | None:
    """The ``regions`` form field as one template cover per spectra operand (None when not
    sent), each token read against the spectrum it is sent with; checked before anything is
    solved."""
    if text is None or signer is None:
        return None
    tokens = form_json.loads(text, "regions", InvalidRegion)
    values = parse_spectra(spectra, models.k)
    if not isinstance(tokens, list) or len(tokens) != len(values):
        raise InvalidRegion(f"regions must be a JSON list of region tokens, one per spectra operand ({len(values)})")
    vertices = len(models.template.vertices)
    return [
        signer.read(token, np.asarray(spectrum), vertices, f"regions[{i}]")
        for i, (token, spectrum) in enumerate(zip(tokens, values, strict=True))
    ]


def _check_measurable(
    overlaps: list[float] | None, boundaries: list[float] | None, spectra: str | None, models: SpectralModels
) -> None:
    """Before anything is solved: a measured overlap needs every operand uploaded (a spectrum has
    no geometry), no told one (nor boundary share) beside it, and models that read it."""
    if overlaps is not None or boundaries is not None:
        raise InvalidOverlap("give overlap (and boundary) or measure_overlap, not both")
    if spectra is not None and spectra.strip():
        raise InvalidOverlap("measure_overlap measures uploaded files; spectra operands have no geometry to measure")
    require_overlap_reader(models.reads_overlap)


@dataclass(frozen=True)
class UnionRequest:
    """What a union-based route was sent, solved when the route asks: after FastAPI has checked
    the route's own parameters, so a malformed one is refused before any upload costs a solve."""

    request: Request
    settings: Settings
    models: SpectralModels
    told: Told
    operands: SentOperands

    async def solved(self, *, cap_holes: bool = False, locate: bool = False) -> UnionOutcome:
        """The union of the operands (:func:`union_of_operands`)."""
        return await union_of_operands(
            self.request, self.settings, self.models, self.operands, self.told, cap_holes=cap_holes, locate=locate
        )


def union_request(
    request: Request, settings: SettingsDep, models: ModelsDep, told: ToldDep, operands: OperandsDep
) -> UnionRequest:
    return UnionRequest(request, settings, models, told, operands)


UnionDep = Annotated[UnionRequest, Depends(union_request)]
