"""The CLI prints what the API returns, and a problem on stderr for bad input."""

import json

import numpy as np
import pytest
from fastapi.testclient import TestClient
from typer.testing import CliRunner

from app.cli import cli
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum, spectrum_from_bytes
from app.main import create_app
from app.samples import BODY_FILE, PARTS, SESSION_SCANS, SPECTRA_FILE
from harness.builders import ascii_ply
from tests.api.conftest import settings_for
from tests.conftest import sphere


def test_spectrum_command_prints_the_report(tmp_path, patch):
    path = tmp_path / "patch.ply"
    path.write_bytes(ascii_ply(patch.vertices * 100, patch.faces))
    result = CliRunner().invoke(cli, ["spectrum", str(path), "--k", "6", "--units", "cm"])
    assert result.exit_code == 0, result.output
    report = json.loads(result.stdout)
    expected = mesh_spectrum(patch, SpectrumOptions(k=6)).eigenvalues
    np.testing.assert_allclose(report["eigenvalues"], expected, rtol=1e-8)


def test_spectrum_command_reports_bad_input(tmp_path):
    path = tmp_path / "scan.zip"
    path.write_bytes(b"PK\x03\x04")
    result = CliRunner().invoke(cli, ["spectrum", str(path)])
    assert result.exit_code == 2
    assert json.loads(result.stderr)["type"] == "/problems/unsupported-file-type"


def test_spectrum_command_warns_of_a_unit_slip_on_stderr(tmp_path, patch):
    path = tmp_path / "patch_mm.ply"
    path.write_bytes(ascii_ply(patch.vertices * 1000, patch.faces))  # millimetres, given as metres
    result = CliRunner().invoke(cli, ["spectrum", str(path), "--k", "6"])
    assert result.exit_code == 0, result.output
    assert "warning:" in result.stderr and "units=mm" in result.stderr
    assert json.loads(result.stdout)["warnings"] == [result.stderr.removeprefix("warning: ").strip()]


def test_samples_command_writes_what_the_readme_uses(tmp_path):
    result = CliRunner().invoke(cli, ["samples", str(tmp_path / "samples")])
    assert result.exit_code == 0, result.output
    folder = tmp_path / "samples"
    names = {*PARTS, BODY_FILE, SPECTRA_FILE, *SESSION_SCANS}
    assert {p.name for p in folder.iterdir()} == names
    assert all(f"wrote {folder / name}" in result.stdout for name in names)
    reports = [spectrum_from_bytes((folder / n).read_bytes(), "ply", SpectrumOptions()) for n in [BODY_FILE, *PARTS]]
    body, *parts = reports
    assert body.boundary == "none" and abs(body.eigenvalues[0]) < 1e-6
    assert [p.boundary for p in parts] == ["dirichlet", "dirichlet"]
    scans = [spectrum_from_bytes((folder / n).read_bytes(), "ply", SpectrumOptions()) for n in SESSION_SCANS]
    assert [scan.boundary for scan in scans] == ["dirichlet", "dirichlet"]  # partial scans, for the page
    spectra = json.loads((folder / SPECTRA_FILE).read_text())
    expected = [parts[0].eigenvalues, parts[1].eigenvalues]  # in PARTS order, as the spectra field takes them
    np.testing.assert_allclose(spectra, expected, rtol=1e-12)


@pytest.fixture(scope="module")
def api(tmp_path_factory):
    """The service in process, to hold the CLI's answers against."""
    with TestClient(create_app(settings_for(tmp_path_factory.mktemp("db") / "shapes.sqlite"))) as client:
        yield client


def test_cli_problems_carry_the_apis_problem_types(tmp_path, patch, api):
    path = tmp_path / "patch.ply"
    path.write_bytes(ascii_ply(patch.vertices, patch.faces))
    for options, query in ((["--units", "inches"], {"units": "inches"}), (["--k", "500"], {"k": 500})):
        result = CliRunner().invoke(cli, ["spectrum", str(path), *options])
        over_http = api.post("/v1/spectrum", params=query, files={"file": ("patch.ply", path.read_bytes())})
        assert result.exit_code == 2
        problem = json.loads(result.stderr)
        assert problem["type"] == over_http.json()["type"] == "/problems/invalid-request"
        assert problem["status"] == over_http.status_code == 422


def test_cli_takes_a_point_clouds_boundary_as_the_api_does(tmp_path, api):
    points = sphere(subdivisions=4).vertices
    points = points[points[:, 2] > 0]
    indices = np.flatnonzero(points[:, 2] < 0.08).tolist()
    path = tmp_path / "cap.xyz"
    path.write_text("".join(f"{x} {y} {z}\n" for x, y, z in points))
    result = CliRunner().invoke(cli, ["spectrum", str(path), "--boundary", json.dumps(indices), "--pretty"])
    assert result.exit_code == 0, result.output
    over_http = api.post(
        "/v1/spectrum", files={"file": ("cap.xyz", path.read_bytes())}, data={"boundary": json.dumps(indices)}
    ).json()
    assert result.stdout.startswith("{\n  ")  # --pretty: indented
    np.testing.assert_allclose(json.loads(result.stdout)["eigenvalues"], over_http["eigenvalues"], rtol=1e-12)
