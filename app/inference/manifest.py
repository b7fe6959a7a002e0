"""Checksums of the artefacts the service loads, kept next to them in ``MANIFEST.json``.

A truncated download or a half-copied file still parses often enough to give wrong answers;
comparing SHA-256 digests before loading turns that into a clear "models unavailable".
"""

import hashlib
import json
from pathlib import Path

MANIFEST_FILE = "MANIFEST.json"
ARTEFACTS = ("union.onnx", "localizer.onnx", "template.npz", "template.json")


class ModelsCorrupt(ValueError):
    """An artefact is missing or differs from its recorded checksum."""


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_manifest(directory: Path) -> None:
    """Record the digests of the served artefacts (run after every export)."""
    entries = {name: digest(directory / name) for name in ARTEFACTS}
    (directory / MANIFEST_FILE).write_text(json.dumps({"sha256": entries}, indent=1) + "\n")


def verify_manifest(directory: Path) -> None:
    """Raise :class:`ModelsCorrupt` unless every artefact is present and matches the manifest."""
    manifest = directory / MANIFEST_FILE
    if not manifest.exists():
        raise ModelsCorrupt(f"{manifest} is missing: the artefacts cannot be checked")
    recorded = json.loads(manifest.read_text())["sha256"]
    for name in ARTEFACTS:
        path = directory / name
        if not path.exists():
            raise ModelsCorrupt(f"{name} is missing from {directory}")
        if digest(path) != recorded.get(name):
            raise ModelsCorrupt(f"{name} does not match its checksum in {MANIFEST_FILE}")
