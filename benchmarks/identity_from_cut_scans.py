"""Identity from scans cut from a stored shape, end to end: an integrator's check of the service.

    python -m benchmarks.identity_from_cut_scans [--people 12]

People outside the build (men, women and children in turn, each in a random pose of their own) are
each stored with ``POST /v1/shapes`` as one whole posed scan, beside the seed database's 630
shapes; then three scans cut from that same mesh are sent to ``POST /v1/retrieve`` as files:
covering it and covering all of it but the right forearm and hand. As served, a union of
several uploads is ranked by the shape of the body fitted to them; beside it, the covering scans'
union (closed) ranked by its own spectrum (``rebuild=false``), as it was before. How often the
person comes first, how often the shape they were cut from is the first match, and how the answer
was ranked. The service runs in process on its defaults (a scratch SQLite database).

Needs the ``train`` extra (anny) and the served models in ``models/``.
"""

import argparse
import tempfile
from collections import Counter
from dataclasses import replace
from pathlib import Path

import numpy as np
import trimesh
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.inference.template import Template
from app.main import create_app
from app.samples import COVERING_SCANS, SHORT_OF_A_HAND, kept_part
from training.sessions.scans import EVERYONE, people

KEY = "benchmark"
CUTS = {  # (the scans' body parts, rebuild)
    "covering": (COVERING_SCANS, True),
    "covering, by the union's own spectrum": (COVERING_SCANS, False),
    "short of a hand": (SHORT_OF_A_HAND, True),
}


def stored(client: TestClient, body: np.ndarray, template: Template, label: str) -> str:
    """The whole posed body stored under ``label``; its id."""
    ply = trimesh.Trimesh(body, template.faces, process=False).export(file_type="ply")
    response = client.post(
        "/v1/shapes", data={"label": label}, files={"file": ("scan.ply", ply)}, headers={"X-API-Key": KEY}
    )
    response.raise_for_status()
    return response.json()["id"]


def retrieved(
    client: TestClient, body: np.ndarray, template: Template, kept: tuple[tuple[str, ...], ...], rebuild: bool
) -> dict:
    """``/v1/retrieve`` of the scans of ``body`` that keep each of ``kept``'s body parts."""
    posed = replace(template, vertices=body)
    files = [("files", (f"scan{i}.ply", kept_part(posed, parts))) for i, parts in enumerate(kept)]
    response = client.post("/v1/retrieve", params={"top": 5, "rebuild": rebuild}, files=files)
    response.raise_for_status()
    return response.json()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--people", type=int, default=12)
    args = parser.parse_args()
    _, found = people(args.people, seed=5, kinds=EVERYONE)
    rows: dict[str, list[tuple[bool, bool, str]]] = {name: [] for name in CUTS}
    with tempfile.TemporaryDirectory() as scratch:
        settings = Settings(database_path=Path(scratch) / "shapes.sqlite", api_key=KEY)
        with TestClient(create_app(settings)) as client:
            template = Template.load(settings.models_dir)
            ids = [stored(client, person.body, template, person.label) for person in found]
            for person, shape_id in zip(found, ids, strict=True):
                for name, (kept, rebuild) in CUTS.items():
                    answer = retrieved(client, person.body, template, kept, rebuild)
                    first = (answer["people"][0]["label"] == person.label, answer["matches"][0]["id"] == shape_id)
                    rows[name].append((*first, answer["ranked_by"]))
                    print(person.label, name, rows[name][-1], flush=True)
    print("\n| scans cut from each stored scan | people | person first | its shape first | ranked by |")
    print("|---|---|---|---|---|")
    for name, found_rows in rows.items():
        person_first, shape_first = (100 * np.mean([row[i] for row in found_rows]) for i in range(2))
        ranked = ", ".join(f"{by} {count}" for by, count in Counter(row[2] for row in found_rows).items())
        print(f"| {name} | {len(found_rows)} | {person_first:.1f} % | {shape_first:.1f} % | {ranked} |")


if __name__ == "__main__":
    main()
