"""Places relaxed toward the part's edge lengths: the truth (the part itself, turned, moved and
scaled as a person of another size) is a fixed point; noisy places come closer to it; the part's
frame and units change nothing; every edge is relaxed once."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.geometry.descriptors import cloud_inputs, mesh_inputs
from app.geometry.laplacian import point_cloud_operators
from app.inference.relaxation import part_edges, relaxed_places
from tests.conftest import bumpy_patch

TURN = Rotation.from_euler("xyz", [0.4, -1.1, 2.3]).as_matrix()


@pytest.fixture(scope="module")
def part():
    """A curved patch with boundary, ~0.1 m across (a hand's size), and its edges."""
    patch = bumpy_patch(n=600)
    points = 0.05 * patch.vertices
    return points, part_edges(mesh_inputs(points, patch.faces))


def _as_placed(points: np.ndarray) -> np.ndarray:
    """Where a person 1.2 times the part's size would have it on the template: turned and moved."""
    return 1.2 * points @ TURN.T + [0.1, 0.9, -0.2]


def test_places_that_keep_the_parts_edge_lengths_do_not_move(part):
    points, edges = part
    truth = _as_placed(points)
    moved = relaxed_places(truth, np.full(len(points), 0.5), points, edges)
    np.testing.assert_allclose(moved, truth, atol=1e-12)


def test_noisy_places_come_closer_to_the_truth(part):
    points, edges = part
    truth = _as_placed(points)
    # Scattered by a tenth of a mean edge (~5 mm) along each axis: past a few tenths, the scatter
    # lengthens every edge and the person's size read from them with it.
    noisy = truth + np.random.default_rng(1).normal(scale=0.0005, size=truth.shape)
    moved = relaxed_places(noisy, np.full(len(points), 0.5), points, edges)
    before, after = (np.linalg.norm(p - truth, axis=1).mean() for p in (noisy, moved))
    assert after < 0.7 * before


def test_the_parts_frame_and_units_do_not_change_its_relaxed_places(part):
    points, edges = part
    noisy = _as_placed(points) + np.random.default_rng(2).normal(scale=0.004, size=points.shape)
    confidence = np.random.default_rng(3).uniform(size=len(points))
    elsewhere = 100.0 * (points @ TURN + [3.0, -1.0, 0.5])  # the same part, in centimetres, moved
    np.testing.assert_allclose(
        relaxed_places(noisy, confidence, elsewhere, edges),
        relaxed_places(noisy, confidence, points, edges),
        atol=1e-12,
    )


def test_each_edge_is_listed_once_and_a_stencils_padding_is_none():
    square = np.array([[0, 0, 0], [1, 0, 0], [1, 1, 0], [0, 1, 0]], float)
    mesh = mesh_inputs(square, np.array([[0, 1, 2], [0, 2, 3]]), k=2)
    assert part_edges(mesh).tolist() == [[0, 1], [0, 2], [0, 3], [1, 2], [2, 3]]
    cloud = np.random.default_rng(4).uniform(size=(60, 3)) * [1, 1, 0.01]
    inputs = cloud_inputs(cloud, None, k=4, operators=point_cloud_operators(cloud))
    edges = part_edges(inputs)
    assert (edges[:, 0] < edges[:, 1]).all() and len(np.unique(edges, axis=0)) == len(edges)
    table = inputs.stencil.neighbours
    listed = {(min(i, j), max(i, j)) for i, row in enumerate(table) for j in row if i != j}
    assert set(map(tuple, edges.tolist())) == listed
