"""The README's and docs' examples as text and as commands: read from their blocks and run as a
reader runs them. Shared by the test that runs them (``tests/test_readme_examples.py``) and the
script that writes their answers back (``benchmarks/readme_examples.py``)."""

import subprocess
import sys
from pathlib import Path

URL = "http://127.0.0.1:8000"  # as the README writes it; a test runs the commands against its own
KEY = "change-me"
BEGIN, END = "<!-- examples:begin -->", "<!-- examples:end -->"
CLIENT_BEGIN, CLIENT_END = "<!-- client:begin -->", "<!-- client:end -->"


def run_command(command: str, folder: Path, url: str = URL) -> str:
    """What ``command`` prints, run by bash in ``folder`` against ``url``; CalledProcessError
    when it fails (curl -s fails on no answer, jq on no JSON)."""
    return subprocess.run(
        ["bash", "-o", "pipefail", "-c", command.replace(URL, url)],
        cwd=folder,
        capture_output=True,
        text=True,
        check=True,
        timeout=300,
    ).stdout


def readme_commands(text: str) -> list[str]:
    """The commands of a document's examples block, as written there."""
    block = text[text.index(BEGIN) : text.index(END)]
    return [line[2:] for line in block.splitlines() if line.startswith("$ ")]


def client_code(text: str) -> str:
    """The Python client example of the README, as written there."""
    block = text[text.index(CLIENT_BEGIN) : text.index(CLIENT_END)]
    return block.split("```python\n", 1)[1].split("```", 1)[0]


def run_client(code: str, folder: Path, url: str = URL) -> str:
    """What the client example prints, run by this Python in ``folder`` against ``url``."""
    command = [sys.executable, "-c", code.replace(URL, url)]
    return subprocess.run(command, cwd=folder, capture_output=True, text=True, check=True, timeout=300).stdout
