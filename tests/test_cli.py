"""The CLI prints what the API returns, and a problem on stderr for bad input."""

import json

import numpy as np
from typer.testing import CliRunner

from app.cli import cli
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
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
