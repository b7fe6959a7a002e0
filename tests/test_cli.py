"""The CLI prints what the API returns, and a problem on stderr for bad input."""

import json

import numpy as np
from typer.testing import CliRunner

from app.cli import cli
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum, spectrum_from_bytes
from tests.builders import ascii_ply


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
    names = {"no_head_neck.ply", "no_left_forearm_hand.ply", "body.ply", "spectra.json"}
    assert {p.name for p in folder.iterdir()} == names
    assert all(f"wrote {folder / name}" in result.stdout for name in names)
    reports = [
        spectrum_from_bytes((folder / n).read_bytes(), "ply", SpectrumOptions())
        for n in sorted(names - {"spectra.json"})
    ]
    body, *parts = reports  # sorted: body.ply first
    assert body.boundary == "none" and abs(body.eigenvalues[0]) < 1e-6
    assert [p.boundary for p in parts] == ["dirichlet", "dirichlet"]
    spectra = json.loads((folder / "spectra.json").read_text())
    expected = [parts[0].eigenvalues, parts[1].eigenvalues]  # no_head_neck, then no_left_forearm_hand
    np.testing.assert_allclose(spectra, expected, rtol=1e-12)
