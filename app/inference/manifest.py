"""Checksums of the artefacts the service loads, kept next to them in ``MANIFEST.json``, and
the spectrum definition the models were trained on.

A truncated download or a half-copied file still parses often enough to give wrong answers;
comparing SHA-256 digests before loading turns that into a clear "models unavailable". So does a
model trained on spectra computed another way (an older spectrum code): it would load and answer,
wrongly, for every request.
"""

import hashlib
import json
from pathlib import Path

from app.contract import (
    BODY_FILE,
    CORRESPONDENCE_FILE,
    RECONSTRUCTION_FILE,
    SEED_BODIES_FILE,
    SESSIONS_FILE,
    spectrum_definition,
)

MANIFEST_FILE = "MANIFEST.json"
ARTEFACTS = ("union.onnx", "localizer.onnx", "template.npz", "template.json")
# Served when present; recorded and checked like the others when they are.
OPTIONAL_ARTEFACTS = (RECONSTRUCTION_FILE, CORRESPONDENCE_FILE, SESSIONS_FILE, BODY_FILE, SEED_BODIES_FILE)


class ModelsCorrupt(ValueError):
    """An artefact is missing or differs from its recorded checksum."""


def digest(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def write_manifest(directory: Path) -> None:
    """Record the digests of the served artefacts (run after every export)."""
    present = [name for name in OPTIONAL_ARTEFACTS if (directory / name).exists()]
    entries = {name: digest(directory / name) for name in (*ARTEFACTS, *present)}
    manifest = {"sha256": entries, "spectrum_definition": spectrum_definition()}
    (directory / MANIFEST_FILE).write_text(json.dumps(manifest, indent=1) + "\n")


def verify_manifest(directory: Path) -> tuple[str, ...]:
    """Raise :class:`ModelsCorrupt` unless every artefact is present and matches the manifest,
    and the models were trained on this service's spectrum definition. Returns the artefacts
    checked: the required ones and the optional ones the manifest records (an optional file it
    does not record is not to be loaded)."""
    manifest = directory / MANIFEST_FILE
    if not manifest.exists():
        raise ModelsCorrupt(f"{manifest} is missing: the artefacts cannot be checked")
    content = json.loads(manifest.read_text())
    trained_on = content.get("spectrum_definition")
    if trained_on != spectrum_definition():
        raise ModelsCorrupt(
            f"the models were trained on spectrum definition {trained_on}, this service computes "
            f"{spectrum_definition()}: retrain them (make models) or serve the matching version"
        )
    recorded = content["sha256"]
    checked = (*ARTEFACTS, *(name for name in OPTIONAL_ARTEFACTS if name in recorded))
    for name in checked:
        path = directory / name
        if not path.exists():
            raise ModelsCorrupt(f"{name} is missing from {directory}")
        if digest(path) != recorded.get(name):
            raise ModelsCorrupt(f"{name} does not match its checksum in {MANIFEST_FILE}")
    return checked
