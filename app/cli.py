"""``spectral-unions``: the service's command line (compute a spectrum, start the server)."""

import dataclasses
import json
from pathlib import Path
from typing import Annotated, NoReturn

import typer
import uvicorn

from app.api.operands import upload_options
from app.api.problems import Problem, status_for
from app.core.config import get_settings
from app.core.errors import InputError
from app.geometry.io import UNIT_TO_METRES, resolve_file_type
from app.geometry.pipeline import solve_bytes
from app.geometry.spectrum import DEFAULT_K, MAX_K
from app.inference.template import Template
from app.samples import write_samples

cli = typer.Typer(no_args_is_help=True, add_completion=False)


@cli.command()
def spectrum(
    file: Annotated[Path, typer.Argument(exists=True, dir_okay=False, readable=True)],
    k: Annotated[int, typer.Option(help=f"Number of eigenvalues, 1–{MAX_K}.")] = DEFAULT_K,
    units: Annotated[str, typer.Option(help="m, cm or mm")] = "m",
    scale: Annotated[float | None, typer.Option(help="Factor to metres; overrides units.")] = None,
    closed: Annotated[bool, typer.Option(help="Point clouds: the cloud is closed.")] = False,
    boundary: Annotated[str | None, typer.Option(help="Point clouds: JSON list of boundary point indices.")] = None,
    cap_holes: Annotated[
        bool, typer.Option(help="Meshes: cap every boundary loop (a whole-body scan's blind spots).")
    ] = False,
    file_type: Annotated[str | None, typer.Option(help="Overrides the extension.")] = None,
    pretty: Annotated[bool, typer.Option(help="Indented JSON instead of one line.")] = False,
    vectors: Annotated[
        Path | None,
        typer.Option(dir_okay=False, help="Also write the eigenfunctions here, as vectors=true gives them."),
    ] = None,
) -> None:
    """Print the spectrum of FILE as the JSON that POST /v1/spectrum returns; a problem (the
    API's type and title) on stderr and exit code 2 when it cannot."""
    # The API's query validation, with its problem type: a bad k or unit is the request's fault.
    if not 1 <= k <= MAX_K:
        _fail(422, "invalid-request", "Invalid request", f"k: must lie in 1–{MAX_K}, got {k}")
    if units not in UNIT_TO_METRES:
        _fail(422, "invalid-request", "Invalid request", f"units: must be one of m, cm, mm, got {units!r}")
    try:
        options = upload_options(get_settings(), k, units, scale, closed=closed, boundary=boundary, cap_holes=cap_holes)
        solved = solve_bytes(file.read_bytes(), resolve_file_type(file.name, file_type), options, vectors=bool(vectors))
    except InputError as exc:
        _fail(status_for(exc), exc.slug, exc.title, str(exc))
    if vectors:
        vectors.write_bytes(solved.npz())
    for warning in solved.report.warnings:
        typer.echo(f"warning: {warning}", err=True)
    typer.echo(json.dumps(dataclasses.asdict(solved.report), indent=2 if pretty else None))


def _fail(status: int, slug: str, title: str, detail: str) -> NoReturn:
    problem = Problem(type=f"/problems/{slug}", title=title, status=status, detail=detail)
    typer.echo(problem.model_dump_json(), err=True)
    raise typer.Exit(code=2)


@cli.command()
def samples(folder: Annotated[Path, typer.Argument(file_okay=False, help="Where to write (made if absent).")]) -> None:
    """Write the README's sample files into FOLDER: two partial scans, a complete body, their spectra."""
    for path in write_samples(folder, Template.load(get_settings().models_dir)):
        typer.echo(f"wrote {path} ({path.stat().st_size} bytes)")


@cli.command()
def serve(
    host: Annotated[str, typer.Option()] = "127.0.0.1",
    port: Annotated[int, typer.Option()] = 8000,
    workers: Annotated[int, typer.Option(min=1)] = 1,
) -> None:
    """Start the HTTP service on its embedded defaults."""
    uvicorn.run(
        "app.main:create_app",
        factory=True,
        host=host,
        port=port,
        workers=workers,
        timeout_graceful_shutdown=get_settings().shutdown_grace_seconds,
    )


def main() -> None:
    cli()
