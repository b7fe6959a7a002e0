"""The decoder's scores against hand-checked cases (numpy only: run in CI)."""

import numpy as np
import trimesh
from scipy.spatial.transform import Rotation

from app.inference.body import body_height, spectrum_gap, surface_area
from training.reconstruction.evaluate import body_scores, rigidly_aligned


def box() -> tuple[np.ndarray, np.ndarray]:
    """A 1 × 2 × 3 m box standing on z: area 22 m², height 3 m."""
    mesh = trimesh.creation.box(extents=(1.0, 2.0, 3.0))
    return np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces)


def test_area_and_height_of_a_box():
    vertices, faces = box()
    assert np.isclose(surface_area(vertices, faces), 22.0)
    assert body_height(vertices) == 3.0


def test_rigid_alignment_undoes_a_rotation_and_a_shift():
    points = np.random.default_rng(0).normal(size=(50, 3))
    moved = points @ Rotation.from_euler("xyz", [30, -50, 110], degrees=True).as_matrix().T + [0.3, -2.0, 5.0]
    np.testing.assert_allclose(rigidly_aligned(moved, points), points, atol=1e-12)


def test_rigid_alignment_never_reflects():
    """A mirror image is not a rigid motion: it stays apart from the original."""
    points = np.random.default_rng(1).normal(size=(50, 3))
    mirrored = points * [-1.0, 1.0, 1.0]
    assert np.abs(rigidly_aligned(mirrored, points) - points).max() > 0.1


def test_scores_of_a_moved_body_are_zero_and_of_a_scaled_one_are_its_scale():
    vertices, faces = box()
    moved = vertices @ Rotation.from_euler("z", 40, degrees=True).as_matrix().T + [1.0, 2.0, 0.0]
    zero = body_scores(moved[None], vertices[None], faces)
    assert zero["vertex_mean_mm"] < 1e-9 and zero["height_mm"] < 1e-9 and zero["area_relative"] < 1e-12
    centre = vertices.mean(0)
    scaled = body_scores((centre + 1.1 * (vertices - centre))[None], vertices[None], faces)
    assert np.isclose(scaled["height_mm"], 300.0)  # 10 % of 3 m
    assert np.isclose(scaled["area_relative"], 0.21)  # 1.1² − 1
    # Every box corner is √(0.5² + 1² + 1.5²) m from the centre and moves by a tenth of that.
    assert np.isclose(scaled["vertex_mean_mm"], 100 * np.sqrt(3.5))


def test_spectrum_gap_ignores_the_zero_eigenvalue_of_a_closed_body():
    target = np.array([0.0, 1.0, 2.0, 4.0])
    assert np.isclose(spectrum_gap(np.array([1e-3, 1.1, 2.2, 4.4]), target), 0.1)
