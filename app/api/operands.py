"""Operands of the spectral endpoints: uploaded files and spectra the client already has.

Files (multipart field ``files``, repeated) are solved server-side by the solver workers
(``app.api.solver``), all of a request's files at once; spectra (form field ``spectra``, a JSON list of eigenvalue
lists) are checked. Operands are taken in that order: files as uploaded, then spectra. An
error names the operand it is about.
"""

import asyncio
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

from fastapi import Depends, File, Form, Query, Request, UploadFile

from app.api import form_json
from app.api.admission import take_solves
from app.api.problems import ProblemError
from app.api.solver import SolverPool
from app.core.config import Settings
from app.core.errors import InputError
from app.geometry.descriptors import Places
from app.geometry.formats import listed
from app.geometry.io import resolve_file_type
from app.geometry.overlap import Footprint
from app.geometry.pipeline import Solved, SpectrumOptions, SpectrumReport
from app.geometry.placing import Part
from app.inference.models import InvalidOverlap
from app.inference.spectra import InvalidSpectrum, checked_spectrum

MAX_OPERANDS = 32
OPERAND_FIELDS = ("files", "spectra")  # the form fields that carry operands

# The operand parameters of every union-based route.
FilesField = Annotated[
    list[UploadFile] | None,
    File(max_length=MAX_OPERANDS, description="Partial scans, one operand each: " + listed()),
]
SpectraField = Annotated[
    str | None,
    Form(description="JSON list of eigenvalue lists (1/m², ascending), e.g. a previous union.", examples=["[[...]]"]),
]
UnitsQuery = Annotated[Literal["m", "cm", "mm"], Query(description="Units of the uploaded files.")]
ScaleQuery = Annotated[float | None, Query(gt=0, description="Factor to metres for the files; overrides units.")]
OverlapQuery = Annotated[
    str | None,
    Query(
        description="Where the client knows it (e.g. from a scanner's tracked camera poses): the share of the "
        "smaller operand's area lying inside the other, 0 to 1, one per union step, comma-separated (operands "
        "− 1 of them: the union so far and the next operand), e.g. 0.94 or 1,0.6. Two part spectra do not "
        "tell how much the parts overlap: told it, the operator need not guess (the model card measures what "
        "it gains). Omit it when unknown.",
        max_length=4096,
        examples=["0.94"],
    ),
]


@dataclass(frozen=True)
class SentOperands:
    """What a union-based request sent as operands: uploaded files, spectra (the form field's
    text, checked when resolved) and the files' units."""

    files: list[UploadFile]
    spectra: str | None
    units: Literal["m", "cm", "mm"] = "m"
    scale: float | None = None


def sent_operands(
    files: FilesField = None, spectra: SpectraField = None, units: UnitsQuery = "m", scale: ScaleQuery = None
) -> SentOperands:
    """The one declaration of the operand parameters every union-based route takes."""
    return SentOperands(files or [], spectra, units, scale)


OperandsDep = Annotated[SentOperands, Depends(sent_operands)]


@dataclass(frozen=True)
class Wanted:
    """What a route needs of each uploaded file beyond its spectrum."""

    footprints: bool = False  # where it lies (app.geometry.overlap): registered views are measured
    cap_holes: bool = False  # its holes capped: the one operand is a whole-body scan
    place_with: Path | None = None  # the correspondence graph: where it lies on the template


SPECTRA_ONLY = Wanted()


CapHolesQuery = Annotated[
    bool,
    Query(
        description="Meshes: cap every boundary loop before the solve, not only pin-holes: a whole-body scan's "
        "blind spots (soles, top of the head), for the closed surface's spectrum that stored complete shapes have. "
        "Not for partial scans, whose boundary is what a union reads."
    ),
]
MeasureOverlapQuery = Annotated[
    bool,
    Query(
        description="The uploaded files are views of one body in one coordinate frame and one pose (a scanner's "
        "registered views): measure the overlap and the boundary share of each union step from them instead of "
        "being told them (app.geometry.overlap). Every operand must be an uploaded file; not with overlap.",
    ),
]
BoundaryQuery = Annotated[
    str | None,
    Query(
        description="Beside overlap, where the client knows it (/v1/overlap measures it from registered views): "
        "how much of the two operands' boundary length is left on their union's boundary, 0 to 1 (0: the union "
        "is closed; 1: neither covers any of the other's boundary), one per union step, comma-separated, e.g. "
        "0.55. With the overlap it tells the union's boundary length besides its area: a view that closes a "
        "session's holes adds little area but much of the spectrum's fall. Omit it when unknown.",
        max_length=4096,
        examples=["0.55"],
    ),
]


RegionsField = Annotated[
    str | None,
    Form(
        description="JSON list of region tokens, one per spectra operand, in order: where on the template each "
        "spectrum's part lies, as /v1/correspondence (region.token) or /v1/localize (region_token) answered it "
        "for the part or the union so far. With them the union's region is the union of its operands' regions "
        "(uploaded files are placed by the correspondence model) and each step's overlap is measured on the "
        "template, as for uploads alone.",
        examples=['["region1:AAAA…"]'],
    ),
]


@dataclass(frozen=True)
class Told:
    """What a request tells of its union steps: the overlap and boundary shares as sent (text;
    None where not told), that they are to be measured from the uploads, and where its spectra
    operands lie on the template (region tokens, JSON text)."""

    overlap: str | None = None
    boundary: str | None = None
    measure: bool = False
    regions: str | None = None


def told_query(
    overlap: OverlapQuery = None,
    boundary: BoundaryQuery = None,
    measure_overlap: MeasureOverlapQuery = False,
    regions: RegionsField = None,
) -> Told:
    """The union routes' query parameters on what is told of each step, and the spectra
    operands' regions (a form field), as one."""
    return Told(overlap, boundary, measure_overlap, regions)


NOT_TOLD = Told()


def parse_shares(text: str | None, name: str = "overlap") -> list[float] | None:
    """A comma-separated query parameter of shares (``overlap``, ``boundary``) as one number per
    union step (None: not told); ranges are checked against the operands later."""
    if text is None:
        return None
    try:
        return [float(value) for value in text.split(",")]
    except ValueError:
        raise InvalidOverlap(f"{name} must be comma-separated numbers, got {text[:40]!r}") from None


@dataclass(frozen=True)
class Operand:
    source: str  # "files[0] scan.ply" or "spectra[1]"
    eigenvalues: list[float]
    report: SpectrumReport | None  # what the solve found, for files
    footprint: Footprint | None = None  # where an uploaded shape lies, when asked for
    part: Part | None = None  # an upload as the correspondence graph places it, when asked for
    places: Places | None = None  # where the network placed it, when the solver worker did


def parse_spectra(text: str | None, k: int) -> list[list[float]]:
    """The ``spectra`` form field as checked eigenvalue lists."""
    if text is None or not text.strip():
        return []
    values = form_json.loads(text, "spectra", InvalidSpectrum)
    if not isinstance(values, list) or not all(isinstance(v, list) for v in values):
        raise InvalidSpectrum("spectra must be a JSON list of eigenvalue lists")
    return [
        checked_spectrum(form_json.number_list(value, f"spectra[{i}]", InvalidSpectrum), k, f"spectra[{i}]").tolist()
        for i, value in enumerate(values)
    ]


def upload_options(
    settings: Settings,
    k: int,
    units: str,
    scale: float | None,
    *,
    closed: bool = False,
    boundary: str | None = None,
    cap_holes: bool = False,
) -> SpectrumOptions:
    """Solve options for an uploaded shape under the service's caps (the API's and the CLI's);
    ``boundary`` is the JSON field of a point cloud's boundary indices."""
    return SpectrumOptions(
        k=k,
        units=units,
        scale=scale,
        closed=closed,
        boundary_indices=form_json.boundary_indices(boundary),
        max_vertices=settings.max_vertices,
        max_hole_edges=settings.max_hole_edges,
        cap_holes=cap_holes,
        placed_vertices=settings.placed_vertices,
    )


async def solve_upload(request: Request, data: bytes, file_type: str, options: SpectrumOptions) -> SpectrumReport:
    """One uploaded shape's spectrum, from the service's solver workers (bounded, with a deadline)."""
    solver: SolverPool = request.app.state.solver
    return await solver.solve(data, file_type, options)


async def _no_operand(request: Request) -> str:
    """Why a request has no operand, naming the fields it sent instead (``file`` for ``files``)."""
    form = await request.form()
    others = sorted(set(form.keys()) - set(OPERAND_FIELDS))
    sent = f"; it sent {', '.join(repr(name) for name in others)}, which is not one" if others else ""
    return (
        "no operand: send scans in the multipart field 'files' (repeated, one per scan) and/or spectra "
        f"in the field 'spectra'{sent}"
    )


@dataclass(frozen=True)
class CountedOperands:
    """A request's operands parsed and counted, nothing solved yet: the uploaded files as sent and
    the spectra checked, so that whatever depends on how many operands there are (the overlaps
    told per step) is checked before any upload costs a solve."""

    sent: SentOperands
    spectra: list[list[float]]

    @property
    def count(self) -> int:
        return len(self.sent.files) + len(self.spectra)


async def counted_operands(request: Request, sent: SentOperands, k: int, cap_holes: bool = False) -> CountedOperands:
    """The operands parsed and counted: at least one, at most ``MAX_OPERANDS``, and with
    ``cap_holes`` exactly one uploaded scan (its holes capped before the solve)."""
    counted = CountedOperands(sent, parse_spectra(sent.spectra, k))
    files, count = sent.files, counted.count
    if count == 0:
        raise ProblemError(422, "invalid-request", "Invalid request", await _no_operand(request))
    if count > MAX_OPERANDS:
        raise ProblemError(
            422,
            "invalid-request",
            "Invalid request",
            f"at most {MAX_OPERANDS} operands (files and spectra), got {count}",
        )
    if cap_holes and (len(files) != 1 or counted.spectra):
        raise ProblemError(
            422,
            "invalid-request",
            "Invalid request",
            f"cap_holes closes one uploaded scan of a whole body, got {len(files)} files and "
            f"{len(counted.spectra)} spectra: the union operator reads partial scans by their boundary",
        )
    return counted


async def resolve_operands(
    request: Request, settings: Settings, counted: CountedOperands, k: int, wanted: Wanted = SPECTRA_ONLY
) -> tuple[list[Operand], float]:
    """Every operand's spectrum, uploaded files solved, and the milliseconds that took; ``wanted``
    says what else each uploaded file's operand carries."""
    sent = counted.sent
    files = sent.files
    options = upload_options(settings, k, sent.units, sent.scale, cap_holes=wanted.cap_holes)
    sources = [f"files[{index}] {upload.filename or ''}".strip() for index, upload in enumerate(files)]
    started = time.perf_counter()
    outcomes = await _solve_all(request, files, options, wanted)
    solve_ms = (time.perf_counter() - started) * 1e3
    for source, outcome in zip(sources, outcomes, strict=True):
        if isinstance(outcome, InputError):
            outcome.args = (f"{source}: {outcome}",)
        if isinstance(outcome, BaseException):
            raise outcome  # the first failing file, in upload order
    operands = [
        Operand(source, solved.report.eigenvalues, solved.report, solved.footprint, solved.part, solved.places)
        for source, solved in zip(sources, outcomes, strict=True)
    ]
    operands += [Operand(f"spectra[{i}]", values, None) for i, values in enumerate(counted.spectra)]
    return operands, solve_ms


async def _solve_all(
    request: Request, files: list[UploadFile], options: SpectrumOptions, wanted: Wanted
) -> list[Solved | BaseException]:
    """Every file solved at once on the solver pool (a union of two scans costs one solve's
    latency, not two), each outcome in upload order: a report, or the exception it raised.
    Every solve runs to its end (each is bounded by the pool's deadline and caps), so a failure
    is reported for the first failing file whatever order the workers finish in."""

    solver: SolverPool = request.app.state.solver
    take_solves(request.state, len(files))

    async def solve(upload: UploadFile) -> Solved:
        data = await upload.read()
        file_type = resolve_file_type(upload.filename, None)
        return await solver.solve_with_functions(
            data, file_type, options, vectors=False, footprint=wanted.footprints, place_with=wanted.place_with
        )

    return list(await asyncio.gather(*(solve(upload) for upload in files), return_exceptions=True))
