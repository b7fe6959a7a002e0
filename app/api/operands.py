"""Operands of the spectral endpoints: uploaded files and spectra the client already has.

Files (multipart field ``files``, repeated) are solved server-side, off the event loop, with
the service's bounded concurrency; spectra (form field ``spectra``, a JSON list of eigenvalue
lists) are checked. Operands are taken in that order: files as uploaded, then spectra. An
error names the operand it is about.
"""

import json
import time
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from typing import Literal

import anyio
import numpy as np
from fastapi import Request, UploadFile

from app.api.metrics import SOLVES
from app.api.problems import ProblemError
from app.core.config import Settings
from app.geometry.errors import GeometryError
from app.geometry.io import resolve_file_type
from app.geometry.pipeline import SpectrumOptions, SpectrumReport, spectrum_from_bytes
from app.inference.spectra import InvalidSpectrum, checked_spectrum

MAX_OPERANDS = 32
RETRY_AFTER_SECONDS = 1  # a solve takes ~0.1–0.3 s: a queue slot frees within a second


@dataclass(frozen=True)
class Operand:
    source: str  # "files[0] scan.ply" or "spectra[1]"
    eigenvalues: list[float]
    report: SpectrumReport | None  # what the solve found, for files


def parse_spectra(text: str | None, k: int) -> list[list[float]]:
    """The ``spectra`` form field as checked eigenvalue lists."""
    if text is None or not text.strip():
        return []
    try:
        values = json.loads(text)
    except json.JSONDecodeError as exc:
        raise InvalidSpectrum(f"spectra must be a JSON list of eigenvalue lists: {exc}") from exc
    if not isinstance(values, list) or not all(isinstance(v, list) for v in values):
        raise InvalidSpectrum("spectra must be a JSON list of eigenvalue lists")
    checked = []
    for index, value in enumerate(values):
        try:
            array = np.asarray(value, dtype=np.float64)
        except (TypeError, ValueError) as exc:
            raise InvalidSpectrum(f"spectra[{index}] must hold numbers only") from exc
        checked.append(checked_spectrum(array, k, f"spectra[{index}]").tolist())
    return checked


def upload_options(settings: Settings, k: int, units: Literal["m", "cm", "mm"], scale: float | None) -> SpectrumOptions:
    """Solve options for an uploaded shape under the service's caps."""
    return SpectrumOptions(
        k=k, units=units, scale=scale, max_vertices=settings.max_vertices, max_hole_edges=settings.max_hole_edges
    )


class SolveSlots:
    """Bounded admission to the eigen-solves: ``concurrency`` run, ``queue`` more may wait.

    The count is taken and raised with no await in between, so concurrent requests on the
    event loop cannot all slip past the check; beyond the bound an upload is refused at once
    (503 with ``Retry-After``) instead of joining a backlog that would time its client out.
    """

    def __init__(self, concurrency: int, queue: int) -> None:
        self.limiter = anyio.CapacityLimiter(concurrency)
        self.capacity = concurrency + queue
        self.admitted = 0

    @contextmanager
    def admission(self) -> Iterator[anyio.CapacityLimiter]:
        if self.admitted >= self.capacity:
            raise ProblemError(
                503,
                "overloaded",
                "Overloaded",
                f"{self.admitted} uploads are already being solved or waiting; retry after {RETRY_AFTER_SECONDS} s.",
                headers={"Retry-After": str(RETRY_AFTER_SECONDS)},
            )
        self.admitted += 1
        try:
            yield self.limiter
        finally:
            self.admitted -= 1


async def solve_upload(request: Request, data: bytes, file_type: str, options: SpectrumOptions) -> SpectrumReport:
    """One uploaded shape's spectrum, solved off the event loop within the service's solve slots."""
    slots: SolveSlots = request.app.state.solve_slots
    with slots.admission() as limiter:
        report = await anyio.to_thread.run_sync(spectrum_from_bytes, data, file_type, options, limiter=limiter)
    SOLVES.observe((report.assembly_ms + report.solve_ms) / 1e3)
    return report


async def resolve_operands(
    request: Request,
    settings: Settings,
    files: list[UploadFile] | None,
    spectra: str | None,
    k: int,
    units: Literal["m", "cm", "mm"],
    scale: float | None,
) -> tuple[list[Operand], float]:
    """Every operand's spectrum (at least one), and the milliseconds spent solving uploaded files."""
    given = parse_spectra(spectra, k)
    files = files or []
    count = len(files) + len(given)
    if not 1 <= count <= MAX_OPERANDS:
        raise InvalidSpectrum(f"expected 1 to {MAX_OPERANDS} operands (files and spectra), got {count}")
    options = upload_options(settings, k, units, scale)
    operands: list[Operand] = []
    started = time.perf_counter()
    for index, upload in enumerate(files):
        source = f"files[{index}] {upload.filename or ''}".strip()
        data = await upload.read()
        try:
            report = await solve_upload(request, data, resolve_file_type(upload.filename, None), options)
        except GeometryError as exc:
            exc.args = (f"{source}: {exc}",)
            raise
        operands.append(Operand(source, report.eigenvalues, report))
    solve_ms = (time.perf_counter() - started) * 1e3
    operands += [Operand(f"spectra[{i}]", values, None) for i, values in enumerate(given)]
    return operands, solve_ms
