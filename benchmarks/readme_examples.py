"""Run the README's API examples against a live service and write what it answered.

    SPECTRAL_UNIONS_API_KEY=change-me make run            # in one shell
    .venv/bin/python benchmarks/readme_examples.py         # in another

Writes the samples (``spectral-unions samples``) to a temporary folder, sends the README's
requests with httpx, and replaces the block between ``<!-- examples:begin -->`` and
``<!-- examples:end -->`` in ``README.md`` with the commands and their answers (long lists cut
to three values), and ``app/api/examples.json`` (the OpenAPI page's success examples) with the
answers rounded to three decimals. Run it after the models change, so that no example shows
what an earlier model said.
"""

import argparse
import json
import tempfile
from pathlib import Path

import httpx

from app.core.config import Settings
from app.geometry.overlap import TOKEN_PREFIX
from app.inference.correspondence import REGION_TOKEN_PREFIX
from app.inference.template import Template
from app.samples import sample_overlap, write_samples

ROOT = Path(__file__).resolve().parents[1]
README, EXAMPLES = ROOT / "README.md", ROOT / "app" / "api" / "examples.json"
BEGIN, END = "<!-- examples:begin -->", "<!-- examples:end -->"
PARTS = ("no_head_neck.ply", "no_left_forearm_hand.ply")
KEY = "change-me"
TOKEN_SHOWN = 24  # characters of a footprint token shown and recorded


def rounded(value):
    """Numbers to three decimals, recursively."""
    if isinstance(value, float):
        return round(value, 3)
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


def files(folder: Path) -> list[tuple[str, tuple[str, bytes, str]]]:
    return [("files", (name, (folder / name).read_bytes(), "application/octet-stream")) for name in PARTS]


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--url", default="http://127.0.0.1:8000")
    args = parser.parse_args()
    url = args.url
    both = "-F files=@no_head_neck.ply -F files=@no_left_forearm_hand.ply"
    blocks, recorded = [], {}
    with tempfile.TemporaryDirectory() as scratch, httpx.Client(base_url=url, timeout=120) as client:
        folder = Path(scratch)
        write_samples(folder, Template.load(Settings().models_dir))

        def show(command: str, response: httpx.Response, name: str | None = None) -> dict:
            """A JSON answer, shown cut and, under ``name``, recorded for the OpenAPI page."""
            body = response.json()
            if name:
                recorded[name] = rounded(body)
            blocks.append(f"$ {command}\n{shown(body)}")
            return body

        def show_text(command: str, text: str) -> None:
            """An answer shown as it is (a header, a status code, metrics lines)."""
            blocks.append(f"$ {command}\n{text}")

        part = (folder / PARTS[0]).read_bytes()
        show(
            f"curl -s -F file=@{PARTS[0]} '{url}/v1/spectrum?units=m'",
            client.post("/v1/spectrum", params={"units": "m"}, files={"file": (PARTS[0], part)}),
            "spectrum",
        )
        show(f"curl -s {both} {url}/v1/union", client.post("/v1/union", files=files(folder)), "union")
        spectra = (folder / "spectra.json").read_text()
        show(
            f'curl -s -F "spectra=$(cat spectra.json)" {url}/v1/union',
            client.post("/v1/union", data={"spectra": spectra}),
        )
        share = round(sample_overlap(Template.load(Settings().models_dir)), 2)
        show(
            f"curl -s -F \"spectra=$(cat spectra.json)\" '{url}/v1/union?overlap={share}'",
            client.post("/v1/union", params={"overlap": share}, data={"spectra": spectra}),
        )
        show(
            f"curl -s {both} '{url}/v1/union?measure_overlap=true'",
            client.post("/v1/union", params={"measure_overlap": "true"}, files=files(folder)),
        )
        views = [
            client.post("/v1/spectrum", params={"footprint": "true"}, files={"file": (n, (folder / n).read_bytes())})
            for n in PARTS
        ]
        view = views[0].json()
        show_text(
            f"curl -s -F file=@{PARTS[0]} '{url}/v1/spectrum?footprint=true' > view0.json  # view1.json: {PARTS[1]}",
            shown({k: view[k] for k in ("eigenvalues", "area_m2", "footprint")}),
        )
        tokens = json.dumps([v.json()["footprint"] for v in views])
        measured = show(
            f"curl -s -F \"footprints=$(jq -sc 'map(.footprint)' view0.json view1.json)\" {url}/v1/overlap",
            client.post("/v1/overlap", data={"footprints": tokens}),
        )
        recorded["overlap"] = rounded({**measured, "union_footprint": measured["union_footprint"][:TOKEN_SHOWN] + "…"})
        placed = client.post("/v1/correspondence", files={"file": (PARTS[0], part)}).json()
        cut = {
            **placed,
            "vertex_indices": placed["vertex_indices"][:3],
            "template_vertex": placed["template_vertex"][:3],
            "position": placed["position"][:3],
            "confidence": placed["confidence"][:3],
            "region": {**placed["region"], "vertices": placed["region"]["vertices"][:5]},
        }
        cut["region"]["token"] = cut["region"]["token"][:TOKEN_SHOWN] + "…"
        recorded["correspondence"] = rounded(cut)
        show_text(f"curl -s -F file=@{PARTS[0]} {url}/v1/correspondence", shown(cut))
        localized = client.post("/v1/localize", files=files(folder)).json()
        token = localized["region_token"] and localized["region_token"][:TOKEN_SHOWN] + "…"
        confidence = localized["vertex_confidence"] and localized["vertex_confidence"][:5]
        localized = {**localized, "vertices": localized["vertices"][:5], "vertex_confidence": confidence}
        recorded["localize"] = rounded({**localized, "region_token": token})
        keys = ("vertices", "area_fraction", "part_coverage", "template_vertices", "located_by")
        region = {k: localized[k] for k in keys}
        show_text(f"curl -s {both} {url}/v1/localize", "(the union's fields as above, then:)\n" + shown(region))
        ply = client.post("/v1/localize", params={"format": "ply"}, files=files(folder)).content
        header = ply[: ply.index(b"end_header")].decode().strip()
        show_text(f"curl -s {both} '{url}/v1/localize?format=ply' -o covered.ply", header)
        rebuilt = client.post("/v1/reconstruct", files=files(folder)).json()
        recorded["reconstruct"] = rounded({**rebuilt, "vertices": rebuilt["vertices"][:3]})
        body = {
            k: rebuilt[k] for k in ("height_m", "area_m2", "body_eigenvalues", "spectrum_relative_error", "vertices")
        }
        show_text(f"curl -s {both} {url}/v1/reconstruct", "(the union's fields as above, then:)\n" + shown(body))
        mesh = client.post("/v1/reconstruct", params={"format": "ply"}, files=files(folder)).content
        header = mesh[: mesh.index(b"end_header")].decode().strip()
        show_text(f"curl -s {both} '{url}/v1/reconstruct?format=ply' -o body.ply", header)
        show(
            f"curl -s {both} '{url}/v1/retrieve?top=3'",
            client.post("/v1/retrieve", params={"top": 3}, files=files(folder)),
            "retrieve",
        )
        added = show(
            f"curl -s -H 'X-API-Key: {KEY}' -F label=alice -F file=@body.ply {url}/v1/shapes",
            client.post(
                "/v1/shapes",
                headers={"X-API-Key": KEY},
                data={"label": "alice"},
                files={"file": ("body.ply", (folder / "body.ply").read_bytes())},
            ),
            "add_shape",
        )
        page = client.get("/v1/shapes", params={"offset": 0, "limit": 2}).json()
        recorded["list_shapes"] = rounded(page)
        shown_page = shown({**page, "shapes": page["shapes"][:1]})[:-2] + ", …]}"
        show_text(f"curl -s '{url}/v1/shapes?offset=0&limit=2'", shown_page)
        deleted = client.delete(f"/v1/shapes/{added['id']}", headers={"X-API-Key": KEY}).status_code
        status_only = "-s -o /dev/null -w '%{http_code}\\n'"
        show_text(f"curl {status_only} -X DELETE -H 'X-API-Key: {KEY}' {url}/v1/shapes/{added['id']}", str(deleted))
        show(f"curl -s {url}/v1/models", client.get("/v1/models"), "models")
        show(f"curl -s {url}/healthz", client.get("/healthz"))
        show(f"curl -s {url}/readyz", client.get("/readyz"))
        metrics = [
            line
            for line in client.get("/metrics").text.splitlines()
            if line.startswith("spectral_unions_requests_total")
        ]
        show_text(
            f"curl -s {url}/metrics | grep -E '^spectral_unions_requests_total' | head -3", "\n".join(metrics[:3])
        )
        show(f"curl -s -F 'spectra=[[1,2,3]]' {url}/v1/union", client.post("/v1/union", data={"spectra": "[[1,2,3]]"}))
        show(
            f"curl -s -X DELETE -H 'X-API-Key: wrong' {url}/v1/shapes/x",
            client.delete("/v1/shapes/x", headers={"X-API-Key": "wrong"}),
        )
    text = README.read_text()
    block = BEGIN + "\n```console\n" + "\n\n".join(blocks) + "\n```\n" + END
    README.write_text(text[: text.index(BEGIN)] + block + text[text.index(END) + len(END) :])
    EXAMPLES.write_text(json.dumps(recorded, indent=1, ensure_ascii=False) + "\n")
    print(f"README.md examples and {EXAMPLES.relative_to(ROOT)} written from {url}")


if __name__ == "__main__":
    main()
