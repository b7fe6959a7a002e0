"""The sample files the README's examples use, made from the template body the service ships.

``spectral-unions samples DIR`` writes them: two partial scans (the template without some of
its body parts, so each has a boundary), a complete body to store, the two parts' spectra as
the ``spectra`` field takes them, and the two scans the README's picture of the session page
was made from (one sees the head, torso and left arm, the other the torso, hips and right
leg). Everything is computed here, from ``models/``, so the examples run from a fresh clone
without a download.
"""

import json
from pathlib import Path

import numpy as np
import trimesh

from app.geometry.io import load_shape
from app.geometry.pipeline import SpectrumOptions, spectrum_from_bytes
from app.geometry.shapes import Mesh
from app.inference.template import PART_NAMES, Template

# File name → the body parts removed from the template (what each name says is missing).
PARTS = {
    "no_head_neck.ply": ("head", "neck"),
    "no_left_forearm_hand.ply": ("left_forearm", "left_hand"),
}
# The session page's two scans, overlapping in the torso: file name → the body parts each keeps.
SESSION_SCANS = {
    "head_torso_left_arm.ply": ("head", "neck", "torso", "left_upper_arm", "left_forearm", "left_hand"),
    "torso_hips_right_leg.ply": ("torso", "hips", "right_thigh", "right_shin", "right_foot"),
}
# Three scans that together cover the body (the session's two and a third for the rest), and the
# same three short of the right forearm and hand: what an integrator cuts from one stored shape.
COVERING_SCANS = (
    *SESSION_SCANS.values(),
    ("torso", "hips", "left_thigh", "left_shin", "left_foot", "right_upper_arm", "right_forearm", "right_hand"),
)
SHORT_OF_A_HAND = (
    *SESSION_SCANS.values(),
    ("torso", "hips", "left_thigh", "left_shin", "left_foot", "right_upper_arm"),
)
BODY_FILE, BODY_SCALE = "body.ply", 1.04  # a complete body of another size: an identity to store
SPECTRA_FILE = "spectra.json"


def _kept_faces(template: Template, removed: tuple[str, ...]) -> np.ndarray:
    """(faces,) which template faces remain when these body parts are removed."""
    keep = ~np.isin(template.labels, [PART_NAMES.index(name) for name in removed])
    return keep[template.faces].all(axis=1)


def template_part(template: Template, removed: tuple[str, ...]) -> bytes:
    """The template body without some of its parts, as PLY bytes: a partial scan with a boundary."""
    mesh = trimesh.Trimesh(template.vertices, template.faces[_kept_faces(template, removed)], process=False)
    mesh.remove_unreferenced_vertices()
    return mesh.export(file_type="ply")


def kept_part(template: Template, kept: tuple[str, ...]) -> bytes:
    """:func:`template_part` holding only the body parts ``kept``."""
    return template_part(template, tuple(name for name in PART_NAMES if name not in kept))


def template_part_mesh(template: Template, removed: tuple[str, ...]) -> Mesh:
    """:func:`template_part` read back by the service's own upload reader: the arrays an upload
    of that file carries, for timing and testing what the service does with it."""
    shape = load_shape(template_part(template, removed), "ply", max_vertices=len(template.vertices))
    if not isinstance(shape, Mesh):
        raise TypeError("a template part's PLY read back as a point cloud")
    return shape


def sample_overlap(template: Template) -> float:
    """The share of the smaller sample part's area inside the other (what ``overlap`` tells the
    union operator): both are the template less some parts, so it is exact from its faces."""
    face_area = trimesh.Trimesh(template.vertices, template.faces, process=False).area_faces
    faces = [_kept_faces(template, removed) for removed in PARTS.values()]
    both = face_area[faces[0] & faces[1]].sum()
    return float(both / min(face_area[f].sum() for f in faces))


def write_samples(folder: Path, template: Template) -> list[Path]:
    """Write the parts, the body, the parts' spectra and the session scans into ``folder``; the
    paths written."""
    folder.mkdir(parents=True, exist_ok=True)
    written, spectra = [], []
    for name, removed in PARTS.items():
        data = template_part(template, removed)
        spectra.append(spectrum_from_bytes(data, "ply", SpectrumOptions()).eigenvalues)
        written.append(_write(folder / name, data))
    body = trimesh.Trimesh(template.vertices * BODY_SCALE, template.faces, process=False)
    written.append(_write(folder / BODY_FILE, body.export(file_type="ply")))
    written.append(_write(folder / SPECTRA_FILE, json.dumps(spectra).encode()))
    for name, kept in SESSION_SCANS.items():
        written.append(_write(folder / name, kept_part(template, kept)))
    return written


def _write(path: Path, data: bytes) -> Path:
    path.write_bytes(data)
    return path
