"""``spectral-unions-train``: build the benchmark data, train, evaluate and export the models."""

from pathlib import Path
from typing import Annotated

import typer

from training.data.build import build_dataset
from training.data.presets import PRESETS

cli = typer.Typer(no_args_is_help=True, add_completion=False)


@cli.callback()
def training() -> None:
    """Data and models for spectral-unions (needs the 'train' extra: torch, anny)."""


@cli.command("build-dataset")
def build_dataset_command(
    out: Annotated[Path, typer.Option(help="Data set directory (resumes if it exists).")] = Path("data/standard"),
    preset: Annotated[str, typer.Option(help=f"One of {', '.join(PRESETS)}.")] = "standard",
    seed: Annotated[int, typer.Option()] = 0,
    scheduler: Annotated[str | None, typer.Option(help="Dask scheduler address, e.g. tcp://host:8786.")] = None,
    workers: Annotated[int | None, typer.Option(help="Local processes (default: all cores).")] = None,
) -> None:
    """Build the anny benchmark: shapes, region pairs, splits and spectra."""
    from training.data.bodies import AnnySource

    if preset not in PRESETS:
        raise typer.BadParameter(f"unknown preset {preset!r}")
    manifest = build_dataset(AnnySource(), PRESETS[preset], out, seed=seed, scheduler=scheduler, workers=workers)
    typer.echo((out / "DATASET_CARD.md").read_text())
    typer.echo(f"{manifest['rows']} rows in {manifest['build_seconds']} s")


@cli.command("build-bodies")
def build_bodies_command(
    out: Annotated[Path, typer.Option(help="Bodies directory for the shape decoder.")] = Path("data/bodies"),
    preset: Annotated[str, typer.Option(help="tiny or standard.")] = "standard",
    seed: Annotated[int, typer.Option()] = 0,
    workers: Annotated[int | None, typer.Option(help="Local processes (default: all cores).")] = None,
    pairs: Annotated[
        bool, typer.Option(help="Also one pair of parts covering each body (for --preset standard-body-unions).")
    ] = False,
    scans: Annotated[
        bool, typer.Option(help="Also each body's blind-spot scan and partial unions (the decoder's scan rows).")
    ] = True,
    template: Annotated[Path, typer.Option(help="The template the parts are cut on (template.npz).")] = Path("models"),
) -> None:
    """Sample anny bodies for the shape decoder: rest-pose vertices and posed complete spectra."""
    from training.reconstruction.bodies import BODIES_PRESETS, build_bodies
    from training.reconstruction.unions import build_body_scans, build_body_unions

    if preset not in BODIES_PRESETS:
        raise typer.BadParameter(f"unknown preset {preset!r}")
    typer.echo(build_bodies(BODIES_PRESETS[preset], out, seed=seed, workers=workers))
    if pairs:
        typer.echo(build_body_unions(out, template, seed=seed, workers=workers))
    if scans:
        typer.echo(build_body_scans(out, template, seed=seed, workers=workers))


DataOption = Annotated[Path, typer.Option(help="A built data set directory.")]
ModelsOption = Annotated[Path, typer.Option(help="Where the ONNX models, metrics and card go.")]
PresetOption = Annotated[
    str, typer.Option(help="Training preset: tiny, standard, or a comparison standard-* (training.union.pipeline).")
]


@cli.command("train")
def train_command(
    data: DataOption = Path("data/standard"),
    runs: Annotated[Path, typer.Option(help="Checkpoints (resumed if present).")] = Path("runs/standard"),
    models: ModelsOption = Path("models"),
    preset: PresetOption = "standard",
    seed: Annotated[int, typer.Option()] = 0,
) -> None:
    """Train the union operator and the localizers, export to ONNX, evaluate, write the model card."""
    _pipeline("train", data, runs, models, preset, seed)


@cli.command("evaluate")
def evaluate_command(
    data: DataOption = Path("data/standard"),
    runs: Annotated[Path, typer.Option(help="Finished checkpoints of `train`.")] = Path("runs/standard"),
    models: ModelsOption = Path("models"),
    preset: PresetOption = "standard",
    seed: Annotated[int, typer.Option()] = 0,
) -> None:
    """Re-export and re-evaluate finished runs without training: metrics.json and the card's tables."""
    _pipeline("evaluate", data, runs, models, preset, seed)


@cli.command("score")
def score_command(
    data: DataOption = Path("data/standard"),
    models: Annotated[Path, typer.Option(help="A folder of exported ONNX models (read only).")] = Path("models"),
    out: Annotated[Path, typer.Option(help="Where the metrics go (JSON).")] = Path("scores.json"),
    seed: Annotated[int, typer.Option()] = 0,
) -> None:
    """Score exported ONNX models on a data set without their checkpoints: the union tables of
    ``evaluate`` (localization by the served localizer only), e.g. an earlier model on new rows."""
    import json

    from training.common.data import SpectralData
    from training.union.evaluate import evaluate
    from training.union.predictors import served_predictors, served_told_predictor

    metrics = evaluate(SpectralData(data, seed=seed), *served_predictors(models), served_told_predictor(models))
    out.write_text(json.dumps(metrics, indent=1))
    typer.echo(f"scored {models} on {data}: {len(metrics['rows'])} rows, {len(metrics['strata'])} strata → {out}")


@cli.command("compare")
def compare_command(
    before: Annotated[Path, typer.Argument(help="metrics of the earlier model (metrics.json or score output)")],
    after: Annotated[Path, typer.Argument(help="metrics of the new model, on the same data set")],
) -> None:
    """Print every table of the card before → after, as Markdown (for the card's prose)."""
    import json

    from training.card.compare import comparison

    typer.echo(comparison(json.loads(before.read_text()), json.loads(after.read_text())), nl=False)


@cli.command("train-decoder")
def train_decoder_command(
    bodies: Annotated[Path, typer.Option(help="A `build-bodies` directory.")] = Path("data/bodies"),
    data: DataOption = Path("data/standard"),
    union_run: Annotated[Path, typer.Option(help="The union operator's finished checkpoint.")] = Path(
        "runs/standard/union.pt"
    ),
    runs: Annotated[Path, typer.Option(help="Checkpoints (resumed if present).")] = Path("runs/standard"),
    models: ModelsOption = Path("models"),
    preset: Annotated[str, typer.Option(help="tiny or standard.")] = "standard",
    seed: Annotated[int, typer.Option()] = 0,
) -> None:
    """Train the shape decoder (spectrum → body), export it, evaluate it on unknown identities."""
    import json

    from training.reconstruction.pipeline import DECODER_PRESETS, run_decoder_pipeline

    if preset not in DECODER_PRESETS:
        raise typer.BadParameter(f"unknown preset {preset!r}")
    command = f"spectral-unions-train train-decoder --bodies {bodies} --data {data} --union-run {union_run}"
    command += f" --runs {runs} --models {models} --preset {preset} --seed {seed}"
    metrics = run_decoder_pipeline(bodies, data, union_run, runs, models, preset, seed, command)
    typer.echo(json.dumps(metrics["sets"], indent=1))


@cli.command("build-parts")
def build_parts_command(
    out: Annotated[Path, typer.Option(help="Parts directory (resumes if it exists).")] = Path("data/parts-standard"),
    preset: Annotated[str, typer.Option(help="tiny or standard.")] = "standard",
    seed: Annotated[int, typer.Option()] = 0,
    workers: Annotated[int | None, typer.Option(help="Local processes (default: all cores).")] = None,
) -> None:
    """Cut anny bodies into parts and pairs with known template correspondences (the correspondence
    model's data)."""
    import json

    from training.correspondence.pairs import build_pairs
    from training.correspondence.parts import PARTS_PRESETS, build_parts

    if preset not in PARTS_PRESETS:
        raise typer.BadParameter(f"unknown preset {preset!r}")
    typer.echo(json.dumps(build_parts(PARTS_PRESETS[preset], out, seed=seed, workers=workers)))
    build_pairs(PARTS_PRESETS[preset], out, seed=seed, workers=workers)


@cli.command("train-correspondence")
def train_correspondence_command(
    parts: Annotated[Path, typer.Option(help="A `build-parts` directory.")] = Path("data/parts-standard"),
    runs: Annotated[Path, typer.Option(help="Checkpoints (a finished one is reused).")] = Path("runs/standard"),
    models: ModelsOption = Path("models"),
    preset: Annotated[str, typer.Option(help="tiny or standard.")] = "standard",
    seed: Annotated[int, typer.Option()] = 0,
) -> None:
    """Train the correspondence model (part → template), export it, evaluate it, write its card section."""
    import json

    from training.correspondence.pipeline import run_correspondence_pipeline
    from training.correspondence.train import TRAINING_PRESETS

    if preset not in TRAINING_PRESETS:
        raise typer.BadParameter(f"unknown preset {preset!r}")
    command = f"spectral-unions-train train-correspondence --parts {parts} --runs {runs} --models {models}"
    command += f" --preset {preset} --seed {seed}"
    metrics = run_correspondence_pipeline(parts, runs, models, preset, seed, command)
    typer.echo(json.dumps(metrics["pairs"], indent=1))


@cli.command("evaluate-correspondence")
def evaluate_correspondence_command(
    parts: Annotated[Path, typer.Option(help="A `build-parts` directory.")] = Path("data/parts-standard"),
    models: ModelsOption = Path("models"),
) -> None:
    """Re-score the served correspondence graph without training it (after a change to how parts
    are placed): its thresholds, parts, pairs and cost, and its card section."""
    import json

    from training.correspondence.pipeline import reevaluate_correspondence

    command = f"spectral-unions-train evaluate-correspondence --parts {parts} --models {models}"
    metrics = reevaluate_correspondence(parts, models, command)
    typer.echo(json.dumps(metrics["pairs"], indent=1))


@cli.command("calibrate-sessions")
def calibrate_sessions_command(
    models: ModelsOption = Path("models"),
    people: Annotated[int, typer.Option(help="Calibration people (scanned as a front-end does).")] = 8,
    held_out: Annotated[int, typer.Option(help="Held-out people the coverage is scored on.")] = 4,
    seed: Annotated[int, typer.Option(help="Calibration people's seed; held-out people use seed + 1.")] = 1,
    test_c: Annotated[int, typer.Option(help="Test C's people the sessions are scored on (at most 9).")] = 6,
) -> None:
    """σ of a registered session's fused union, by view count, from anny sessions with exact truth;
    then the sessions as served scored on Test C's people, into the model card."""
    import json

    from training.sessions.calibrate import calibrate_sessions

    command = f"spectral-unions-train calibrate-sessions --models {models} --people {people} --held-out {held_out}"
    command += f" --seed {seed} --test-c {test_c}"
    content = calibrate_sessions(models, people, held_out, seed, test_c, command)
    typer.echo(json.dumps({"methods": content["methods"], "evaluation": content["evaluation"]}, indent=1))


@cli.command("fit-bodies")
def fit_bodies_command(
    models: ModelsOption = Path("models"),
    people: Annotated[int, typer.Option(help="Calibration people: men, women and children.")] = 9,
    seed: Annotated[int, typer.Option(help="Calibration people's seed.")] = 1,
    test_c: Annotated[int, typer.Option(help="Test C's people the bodies are scored on (at most 9).")] = 6,
) -> None:
    """The body basis sessions are fitted with (the decoder's, posed by anny's skinning per part),
    its intervals calibrated on anny sessions, its bodies and measurements scored on Test C's
    people, into the model card."""
    import json

    from training.sessions.bodies import fit_bodies

    command = f"spectral-unions-train fit-bodies --models {models} --people {people} --seed {seed} --test-c {test_c}"
    content = fit_bodies(models, people, seed, test_c, command)
    typer.echo(json.dumps(content["evaluation"], indent=1))


def _pipeline(verb: str, data: Path, runs: Path, models: Path, preset: str, seed: int) -> None:
    from training.union.pipeline import TRAINING_PRESETS, UnfinishedRuns, run_pipeline

    if preset not in TRAINING_PRESETS:
        raise typer.BadParameter(f"unknown preset {preset!r}")
    command = f"spectral-unions-train {verb} --data {data} --runs {runs} --models {models} --preset {preset}"
    command += f" --seed {seed}"
    try:
        metrics = run_pipeline(data, runs, models, TRAINING_PRESETS[preset], seed, command, train=verb == "train")
    except UnfinishedRuns as error:
        raise typer.BadParameter(str(error), param_hint="--runs") from error
    typer.echo(f"{verb}: {metrics['seconds']} s; parity {metrics['parity_max_relative']}")


def main() -> None:
    cli()
