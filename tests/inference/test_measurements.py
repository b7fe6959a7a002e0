"""Measurements against shapes whose measurements are known by hand, and the laws any length obeys."""

from pathlib import Path

import numpy as np
import pytest
import trimesh

from app.inference.measurements import MEASUREMENTS, Measurer, girth, supported
from app.inference.template import Template

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def template() -> Template:
    return Template.load(MODELS)


def cylinder(radius: float, x: float, sections: int = 64) -> trimesh.Trimesh:
    mesh = trimesh.creation.cylinder(radius=radius, height=1.0, sections=sections)
    mesh.apply_translation([x, 0.0, 0.0])
    return mesh


def test_a_cylinder_s_girth_is_its_polygon_s_perimeter():
    mesh = cylinder(0.15, 0.0)
    everywhere = np.ones(len(mesh.vertices), bool)
    measured = girth(np.asarray(mesh.vertices), np.asarray(mesh.faces), 0.1, everywhere, midline=0.0)
    assert measured == pytest.approx(2 * 64 * 0.15 * np.sin(np.pi / 64), rel=1e-9)


def test_a_girth_bridges_hollows_as_a_tape_does():
    # A star-shaped prism: the tape runs over the points of the star, never into its notches.
    angles = np.linspace(0, 2 * np.pi, 10, endpoint=False)
    radius = np.where(np.arange(10) % 2 == 0, 0.2, 0.08)
    outline = np.column_stack([radius * np.cos(angles), radius * np.sin(angles)])
    bottom = np.column_stack([outline, np.zeros(10)])
    top = np.column_stack([outline, np.ones(10)])
    vertices = np.vstack([bottom, top])
    lower = [[i, (i + 1) % 10, 10 + i] for i in range(10)]
    upper = [[(i + 1) % 10, 10 + (i + 1) % 10, 10 + i] for i in range(10)]
    faces = np.array(lower + upper)
    measured = girth(vertices, faces, 0.5, np.ones(20, bool), midline=0.0)
    points = outline[::2]
    pentagon = np.linalg.norm(points - np.roll(points, 1, axis=0), axis=1).sum()
    assert measured == pytest.approx(pentagon, rel=1e-9)


def test_a_girth_is_taken_round_the_body_not_a_limb_beside_it():
    torso, arm = cylinder(0.15, 0.0), cylinder(0.05, 0.4)
    both = trimesh.util.concatenate([torso, arm])
    vertices, faces = np.asarray(both.vertices), np.asarray(both.faces)
    measured = girth(vertices, faces, 0.1, np.ones(len(vertices), bool), midline=0.0)
    assert measured == pytest.approx(2 * 64 * 0.15 * np.sin(np.pi / 64), rel=1e-9)
    assert girth(vertices, faces, 0.1, np.ones(len(vertices), bool), midline=0.3) is None


def test_every_measurement_is_a_length(template):
    measurer = Measurer.of(template)
    body = template.vertices.astype(np.float64)
    once, larger = measurer.measure(body), measurer.measure(1.1 * body)
    for name in MEASUREMENTS:
        assert larger[name] == pytest.approx(1.1 * once[name], rel=2e-2), name  # slices fall on a 0.5 % grid


def test_the_template_measures_as_a_standing_adult(template):
    measured = Measurer.of(template).measure(template.vertices.astype(np.float64))
    assert measured["stature"] == pytest.approx(np.ptp(template.vertices[:, 2]))
    assert measured["crotch_height"] < measured["stature"] / 2
    assert measured["waist_girth"] < min(measured["chest_girth"], measured["hip_girth"])
    assert 0.2 < measured["shoulder_breadth"] < measured["chest_girth"] / 2


def test_the_shoulder_points_mirror_each_other(template):
    left, right = Measurer.of(template).landmarks.shoulder
    assert template.mirror[left] == right


def test_a_measurement_needs_the_parts_it_rests_on():
    legs = {"hips": 1.0, "left_thigh": 1.0, "left_shin": 0.9, "left_foot": 0.5}
    assert supported("crotch_height", legs, 0.3)
    assert not supported("crotch_height", legs | {"left_foot": 0.1}, 0.3)
    assert not supported("arm_length", legs, 0.3)
