"""Run the README's API examples, as a shell runs them, against a live service, and write what
it answered.

    SPECTRAL_UNIONS_API_KEY=change-me make run            # in one shell
    .venv/bin/python -m benchmarks.readme_examples        # in another

Writes the samples (``spectral-unions samples``) to a temporary folder and runs each command of
:func:`examples` there with bash (curl and jq, as a reader would), then replaces the block
between ``<!-- examples:begin -->`` and ``<!-- examples:end -->`` in ``docs/api.md`` with the
commands and their answers (long lists cut to three values), the same block in ``README.md``
with the tour's few, the Python client example's
printed output with what it prints now, and ``app/api/examples.json`` (the OpenAPI page's
success examples) with the answers rounded to three decimals. What the README
shows is what its commands print, so they run verbatim (``tests/test_readme_examples.py``).
Run it after the models change, so that no example shows what an earlier model said.
"""

import argparse
import json
import tempfile
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

from app.core.config import Settings
from app.geometry.overlap import TOKEN_PREFIX
from app.inference.region_tokens import PREFIX as REGION_TOKEN_PREFIX
from app.inference.template import Template
from app.samples import sample_overlap, write_samples
from harness.readme import (
    BEGIN,
    CLIENT_BEGIN,
    CLIENT_END,
    END,
    KEY,
    URL,
    client_code,
    run_client,
    run_command,
)

ROOT = Path(__file__).resolve().parents[1]
README, API_DOC, EXAMPLES = ROOT / "README.md", ROOT / "docs" / "api.md", ROOT / "app" / "api" / "examples.json"
TOKEN_SHOWN = 24  # characters of a footprint or region token shown and recorded
UNION_THEN = "(the union's fields as above, then:)\n"


def rounded(value):
    """Numbers to three decimals, recursively (a closed surface's λ₁, ±1e-15, shown as 0.0, not -0.0)."""
    if isinstance(value, float):
        return round(value, 3) + 0.0
    if isinstance(value, list):
        return [rounded(v) for v in value]
    if isinstance(value, dict):
        return {k: rounded(v) for k, v in value.items()}
    return value


def shown(value, cut: int = 3) -> str:
    """JSON as the README shows it: rounded, lists over ``cut`` items cut to ``cut`` and "…",
    part coverage cut to four parts, footprint and region tokens to their start."""
    if isinstance(value, str) and value.startswith((TOKEN_PREFIX, REGION_TOKEN_PREFIX)):
        return json.dumps(value[:TOKEN_SHOWN] + "…", ensure_ascii=False)
    if isinstance(value, dict):
        items = list(value.items())
        tail = ""
        if len(items) > 8 and all(isinstance(v, float) for _, v in items):  # part coverage
            items, tail = items[:4], ", …: …"
        return "{" + ", ".join(f"{json.dumps(k)}: {shown(v, cut)}" for k, v in items) + tail + "}"
    if isinstance(value, list):
        if len(value) > cut:
            return "[" + ", ".join(shown(v, cut) for v in value[:cut]) + ", …]"
        return "[" + ", ".join(shown(v, cut) for v in value) + "]"
    return json.dumps(rounded(value), ensure_ascii=False)


def as_json(output: str) -> str:
    return shown(json.loads(output))


def as_text(output: str) -> str:
    return output.rstrip("\n")


def fields(*keys: str, preface: str = "") -> Callable[[str], str]:
    """Show only ``keys`` of a JSON answer, after ``preface``."""
    return lambda output: preface + shown({k: json.loads(output)[k] for k in keys})


def first_of_list(output: str) -> str:
    page = json.loads(output)
    return shown({**page, "shapes": page["shapes"][:1]})[:-2] + ", …]}"


PER_VERTEX_SHOWN = {
    "vertex_indices": 3,
    "template_vertex": 3,
    "position": 3,
    "confidence": 3,
    "vertex_confidence": 5,
    "sigma_m": 3,
}


def cut_tokens(body: dict) -> dict:
    """A recorded answer with its tokens cut and its per-vertex lists shortened (vertex indices
    to five, coordinates to three)."""
    cut = dict(body)
    for key in ("union_footprint", "region_token"):
        if cut.get(key):
            cut[key] = cut[key][:TOKEN_SHOWN] + "…"
    for key, length in PER_VERTEX_SHOWN.items():
        if isinstance(cut.get(key), list):
            cut[key] = cut[key][:length]
    if isinstance(cut.get("vertices"), list) and cut["vertices"]:
        cut["vertices"] = cut["vertices"][: 5 if isinstance(cut["vertices"][0], int) else 3]
    if isinstance(cut.get("views"), list):  # a session's views, each with its region token
        cut["views"] = [{**view, "region_token": view["region_token"][:TOKEN_SHOWN] + "…"} for view in cut["views"]]
    if isinstance(cut.get("region"), dict):
        region = cut["region"]
        cut["region"] = {**region, "vertices": region["vertices"][:5], "token": region["token"][:TOKEN_SHOWN] + "…"}
    return cut


@dataclass(frozen=True)
class Example:
    command: str  # as the README shows it and bash runs it, in the samples folder
    show: Callable[[str], str] = as_json  # what the README shows of its output
    record: str | None = None  # its name among the OpenAPI page's examples, if it is one
    tour: bool = False  # also shown in the README's short tour (docs/api.md shows them all)


def examples(overlap: float) -> list[Example]:
    """The README's examples, in order; later ones read what earlier ones wrote."""
    both = "-F files=@no_head_neck.ply -F files=@no_left_forearm_hand.ply"
    key = f"-H 'X-API-Key: {KEY}'"
    union_fields = ("vertices", "area_fraction", "part_coverage", "template_vertices", "located_by")
    body_fields = (
        "body_by",
        "height_m",
        "area_m2",
        "body_eigenvalues",
        "spectrum_relative_error",
        "vertices",
        "sigma_m",
    )
    footprint = f"'{URL}/v1/spectrum?footprint=true'"
    header = "sed '/end_header/q'"  # a PLY's text header, up to its end
    status = "-o /dev/null -w '%{http_code}\\n'"
    view_route = f"{URL}/v1/sessions/$(jq -r .id session.json)/views"
    session_fields = ("union_by", "eigenvalues", "sigma", "area_fraction", "part_coverage", "least_covered", "warnings")
    return [
        Example(f"curl -s -F file=@no_head_neck.ply '{URL}/v1/spectrum?units=m'", record="spectrum", tour=True),
        Example(f"curl -s {both} {URL}/v1/union", tour=True),
        Example(f'curl -s -F "spectra=$(cat spectra.json)" {URL}/v1/union', tour=True),
        Example(f"curl -s -F \"spectra=$(cat spectra.json)\" '{URL}/v1/union?overlap={overlap}'"),
        Example(f"curl -s {both} '{URL}/v1/union?measure_overlap=true'", record="union"),  # every field set
        Example(
            f"curl -s -F file=@no_head_neck.ply {footprint} | tee view0.json",
            fields("eigenvalues", "area_m2", "footprint"),
        ),
        Example(f"curl -s -F file=@no_left_forearm_hand.ply {footprint} > view1.json", as_text),
        Example("jq -c -s 'map(.footprint)' view0.json view1.json > footprints.json", as_text),
        Example(f"curl -s -F 'footprints=<footprints.json' {URL}/v1/overlap", record="overlap"),
        Example(f"curl -s -F file=@no_head_neck.ply {URL}/v1/correspondence", record="correspondence"),
        Example(f"curl -s {both} {URL}/v1/localize", fields(*union_fields, preface=UNION_THEN), "localize", True),
        Example(f"curl -s {both} '{URL}/v1/localize?format=ply' -o covered.ply && {header} covered.ply", as_text),
        Example(f"curl -s {both} {URL}/v1/reconstruct", fields(*body_fields, preface=UNION_THEN), "reconstruct"),
        Example(f"curl -s {both} '{URL}/v1/reconstruct?format=ply' -o rebuilt.ply && {header} rebuilt.ply", as_text),
        Example(f"curl -s {both} '{URL}/v1/retrieve?top=3'", record="retrieve", tour=True),
        Example(f"curl -s {key} -F label=alice -F file=@body.ply {URL}/v1/shapes | tee alice.json", record="add_shape"),
        Example(f"curl -s '{URL}/v1/shapes?offset=0&limit=2'", first_of_list, "list_shapes"),
        Example(f"curl -s {status} -X DELETE {key} {URL}/v1/shapes/$(jq -r .id alice.json)", as_text),
        Example(
            f"curl -s -H 'content-type: application/json' -d '{{\"registered\": true}}' {URL}/v1/sessions"
            " | tee session.json",
            fields("id", "registered", "union_by", "least_covered"),
            "session",
            True,
        ),
        Example(
            f"curl -s -F file=@head_torso_left_arm.ply {view_route}",
            fields("union_by", "eigenvalues", "sigma", "area_fraction", "least_covered"),
            tour=True,
        ),
        Example(
            f"curl -s -F file=@torso_hips_right_leg.ply {view_route}", fields(*session_fields), "session_view", True
        ),
        Example(f"curl -s {URL}/v1/sessions/$(jq -r .id session.json)", fields("union_by", "views", "eigenvalues")),
        Example(
            f"curl -s {URL}/v1/sessions/$(jq -r .id session.json)/body",
            fields("views", "residual_m", "vertices", "sigma_m", "measurements", "not_measured"),
            "session_body",
            True,
        ),
        Example(
            f'curl -s "{URL}/v1/sessions/$(jq -r .id session.json)/identity?top=3"',
            fields("ranked_by", "people", "warnings"),
            "session_identity",
            True,
        ),
        Example(f"curl -s {status} -X DELETE {URL}/v1/sessions/$(jq -r .id session.json)", as_text),
        Example(f"curl -s {URL}/v1/models", record="models"),
        Example(f"curl -s {URL}/healthz"),
        Example(f"curl -s {URL}/readyz"),
        Example(f"curl -s {URL}/metrics | grep -E '^spectral_unions_requests_total' | head -3", as_text),
        Example(f"curl -s -F 'spectra=[[1,2,3]]' {URL}/v1/union"),
        Example(f"curl -s -X DELETE -H 'X-API-Key: wrong' {URL}/v1/shapes/x"),
    ]


def run(example: Example, folder: Path, url: str = URL) -> str:
    """What ``example``'s command prints (:func:`harness.readme.run_command`)."""
    return run_command(example.command, folder, url)


def with_client_output(text: str, output: str) -> str:
    """The README with the client example's printed output replaced by ``output``."""
    code = client_code(text)
    block = f"{CLIENT_BEGIN}\n```python\n{code}```\n\n```console\n{output.rstrip()}\n```\n{CLIENT_END}"
    return text[: text.index(CLIENT_BEGIN)] + block + text[text.index(CLIENT_END) + len(CLIENT_END) :]


def with_examples(text: str, blocks: list[str]) -> str:
    """``text`` with its examples block replaced by ``blocks``, as a console session."""
    block = BEGIN + "\n```console\n" + "\n\n".join(blocks) + "\n```\n" + END
    return text[: text.index(BEGIN)] + block + text[text.index(END) + len(END) :]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", default=URL)
    args = parser.parse_args()
    template = Template.load(Settings().models_dir)
    shown_blocks, recorded = [], {}
    with tempfile.TemporaryDirectory() as scratch:
        folder = Path(scratch)
        write_samples(folder, template)
        for example in examples(round(sample_overlap(template), 2)):
            output = run(example, folder, args.url)
            shown_blocks.append((example.tour, f"$ {example.command}\n{example.show(output)}".rstrip("\n")))
            if example.record:
                recorded[example.record] = rounded(cut_tokens(json.loads(output)))
        readme = README.read_text()
        readme = with_client_output(readme, run_client(client_code(readme), folder, args.url))
    README.write_text(with_examples(readme, [block for tour, block in shown_blocks if tour]))
    API_DOC.write_text(with_examples(API_DOC.read_text(), [block for _, block in shown_blocks]))
    EXAMPLES.write_text(json.dumps(recorded, indent=1, ensure_ascii=False) + "\n")
    print(f"README.md, docs/api.md and {EXAMPLES.relative_to(ROOT)} written from {args.url}")


if __name__ == "__main__":
    main()
