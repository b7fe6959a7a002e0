"""The documented examples run as they are written: every command of docs/api.md's examples
(the README's tour is a few of them, word for word), by bash in a folder of samples written by
the README's own command, against a live service with a write key; and the README's Python
client example, by this Python. Each must succeed, and answer a problem exactly where the docs
show one. Needs curl and jq (``.ci/run`` installs them)."""

import json
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from harness.readme import KEY, URL, client_code, readme_commands, run_client, run_command
from harness.servers import serving

ROOT = Path(__file__).resolve().parents[1]
README = (ROOT / "README.md").read_text()
API_DOC = (ROOT / "docs" / "api.md").read_text()
pytestmark = pytest.mark.skipif(
    not (shutil.which("curl") and shutil.which("jq")), reason="needs curl and jq (.ci/run installs them)"
)


@pytest.fixture(scope="module")
def service(tmp_path_factory):
    for port in serving(tmp_path_factory.mktemp("db"), SPECTRAL_UNIONS_API_KEY=KEY):
        yield f"http://127.0.0.1:{port}"


@pytest.fixture(scope="module")
def samples(tmp_path_factory) -> Path:
    """The samples folder, written by the command the README gives."""
    folder = tmp_path_factory.mktemp("spectral-samples")
    subprocess.run([str(Path(sys.executable).parent / "spectral-unions"), "samples", str(folder)], check=True)
    return folder


def _shown_answers(text: str) -> list[str]:
    """What the README shows under each command of its examples block (its first line)."""
    lines = text[text.index("<!-- examples:begin -->") : text.index("<!-- examples:end -->")].splitlines()
    return [lines[i + 1] if i + 1 < len(lines) else "" for i, line in enumerate(lines) if line.startswith("$ ")]


def test_the_readme_tour_is_some_of_the_documented_examples_word_for_word():
    documented = readme_commands(API_DOC)
    tour = readme_commands(README)
    assert tour and all(command in documented for command in tour)
    assert [documented.index(command) for command in tour] == sorted(documented.index(command) for command in tour)


def test_every_documented_command_runs_as_written(service, samples):
    commands = readme_commands(API_DOC)
    assert len(commands) >= 20
    for command, shown in zip(commands, _shown_answers(API_DOC), strict=True):
        output = run_command(command, samples, service)
        if output.startswith("{"):
            answer = json.loads(output)
            assert ("/problems/" in str(answer.get("type", ""))) == ("/problems/" in shown), command
        assert URL in command or command.startswith("jq"), command  # the README's address, not the test's


def test_the_client_example_prints_what_the_readme_shows_it_printing(service, samples):
    printed = run_client(client_code(README), samples, service).splitlines()
    shown = README[README.index("<!-- client:begin -->") :].split("```console\n", 1)[1].split("```", 1)[0].splitlines()
    assert len(printed) == len(shown)
    assert printed[-1] == shown[-1]  # the problem it provokes, word for word
