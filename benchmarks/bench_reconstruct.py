"""Latency and answer size of ``POST /v1/reconstruct`` and of ``/v1/retrieve``'s rebuilt-body
ranking, in process, as a client sees it.

Run: ``python benchmarks/bench_reconstruct.py [--repeats 8]``. The operand is the template
body's own complete spectrum (sent as spectra, so no upload is solved); the request decodes it,
writes the rebuilt body as PLY and solves it on the solver workers for the spectrum check.
Prints the median milliseconds and the answer's bytes for JSON and PLY, and ``/v1/union`` on the
same operand for comparison (what the reconstruction adds); then ``/v1/retrieve`` of that closed
spectrum (ranked as it is) and of the template without its soles (an open surface, ranked
through the body rebuilt from it: the same decode and solve).
"""

import argparse
import json
import statistics
import tempfile
import time
from pathlib import Path

from fastapi.testclient import TestClient

from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from app.geometry.topology import drop_unreferenced
from app.inference.template import Template
from app.main import create_app
from training.reconstruction.blind_spots import above_soles

SOLES = 0.015  # m above the lowest vertex: a body scanned standing, its soles unseen


def timed(client: TestClient, path: str, form: dict, params: dict, repeats: int) -> tuple[float, int]:
    """Median milliseconds and the last answer's bytes."""
    times, size = [], 0
    for _ in range(repeats):
        started = time.perf_counter()
        response = client.post(path, data=form, params=params)
        times.append(time.perf_counter() - started)
        assert response.status_code == 200, response.text
        size = len(response.content)
    return 1e3 * statistics.median(times), size


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=8)
    args = parser.parse_args()
    template = Template.load(Settings().models_dir)
    spectrum = mesh_spectrum(Mesh(template.vertices, template.faces), SpectrumOptions(k=20)).eigenvalues
    form = {"spectra": json.dumps([list(spectrum)])}
    seen = above_soles(template.vertices, SOLES)
    scan = Mesh(*drop_unreferenced(template.vertices, template.faces[seen[template.faces].all(axis=1)]))
    open_form = {"spectra": json.dumps([list(mesh_spectrum(scan, SpectrumOptions(k=20)).eigenvalues)])}
    with tempfile.TemporaryDirectory() as scratch:
        settings = Settings(database_path=Path(scratch) / "shapes.sqlite")
        with TestClient(create_app(settings)) as client:
            for label, path, params, operands in (
                ("reconstruct json", "/v1/reconstruct", {}, form),
                ("reconstruct ply", "/v1/reconstruct", {"format": "ply"}, form),
                ("union", "/v1/union", {}, form),
                ("retrieve closed", "/v1/retrieve", {}, form),
                ("retrieve open", "/v1/retrieve", {}, open_form),
            ):
                ms, size = timed(client, path, operands, params, args.repeats)
                print(f"{label:18s} median {ms:7.1f} ms   {size:8d} bytes")


if __name__ == "__main__":
    main()
