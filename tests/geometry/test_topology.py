"""The combinatorial helpers against brute-force counts on random and hand-made meshes."""

from collections import Counter

import numpy as np
import pytest
import trimesh

from app.geometry.intrinsic import _distinct
from app.geometry.topology import (
    drop_unreferenced,
    edge_face_counts,
    face_areas,
    half_edges,
    largest_component,
    row_sums,
)
from app.geometry.validate import _GENERIC, _merge_duplicate_vertices, distinct_faces


def _random_faces(rng: np.random.Generator, vertices: int, faces: int) -> np.ndarray:
    """Triangles with three distinct corners, edges shared by any number of faces."""
    return np.array([rng.choice(vertices, 3, replace=False) for _ in range(faces)])


@pytest.mark.parametrize("seed", range(5))
def test_edge_face_counts_match_a_counter(seed):
    faces = _random_faces(np.random.default_rng(seed), vertices=12, faces=40)
    half = half_edges(faces)
    counts = Counter(frozenset(edge) for edge in half.tolist())
    expected = [counts[frozenset(edge)] for edge in half.tolist()]
    np.testing.assert_array_equal(edge_face_counts(half), expected)


def test_a_closed_surface_has_two_faces_on_every_edge():
    sphere = trimesh.creation.icosphere(subdivisions=2)
    assert np.all(edge_face_counts(half_edges(sphere.faces)) == 2)


def test_drop_unreferenced_keeps_every_face_on_its_coordinates():
    rng = np.random.default_rng(0)
    vertices = rng.standard_normal((30, 3))
    faces = _random_faces(rng, 30, 8)
    kept, renumbered = drop_unreferenced(vertices, faces)
    assert len(kept) == len(np.unique(faces))
    np.testing.assert_array_equal(kept[renumbered], vertices[faces])


@pytest.mark.parametrize("clean", [drop_unreferenced, _merge_duplicate_vertices])
def test_a_clean_mesh_comes_back_as_it_was(clean):
    """No unused and no duplicate vertex: the same arrays, in their own vertex order."""
    sphere = trimesh.creation.icosphere(subdivisions=1)
    vertices, faces = clean(sphere.vertices, sphere.faces)[:2]
    assert vertices is sphere.vertices and faces is sphere.faces


def test_duplicate_vertices_merge_without_moving_any_face():
    sphere = trimesh.creation.icosphere(subdivisions=1)
    # Every face gets its own three vertices, as in STL, then the vertex order is shuffled.
    soup = sphere.vertices[sphere.faces].reshape(-1, 3)
    order = np.random.default_rng(1).permutation(len(soup))
    position = np.empty_like(order)
    position[order] = np.arange(len(order))
    vertices, faces = soup[order], position[np.arange(len(soup)).reshape(-1, 3)]
    merged, merged_faces, sources = _merge_duplicate_vertices(vertices, faces)
    assert len(merged) == len(sphere.vertices)
    np.testing.assert_array_equal(merged[merged_faces], vertices[faces])
    np.testing.assert_array_equal(vertices[sources], merged)  # each kept vertex names an uploaded one


def test_largest_component_is_by_area_and_one_component_is_returned_whole():
    big = trimesh.creation.icosphere(subdivisions=2)
    small = trimesh.creation.icosphere(subdivisions=3, radius=0.1)
    vertices = np.concatenate([small.vertices, big.vertices])
    faces = np.concatenate([small.faces, big.faces + len(small.vertices)])
    kept, dropped = largest_component(vertices, faces)
    assert dropped == 1
    np.testing.assert_array_equal(kept, big.faces + len(small.vertices))
    alone, none_dropped = largest_component(big.vertices, big.faces)
    assert none_dropped == 0 and alone is big.faces


def test_row_sums_are_numpys_to_the_bit():
    """Column by column, in the order NumPy's reduction adds, over magnitudes that round."""
    rows = np.random.default_rng(0).standard_normal((1000, 3)) * 10.0 ** np.random.default_rng(1).integers(
        -8, 8, (1000, 3)
    )
    assert np.array_equal(row_sums(rows), rows.sum(axis=1))


def test_face_areas_are_half_the_cross_products_norm():
    rng = np.random.default_rng(2)
    vertices, faces = rng.standard_normal((50, 3)), _random_faces(rng, 50, 80)
    a, b, c = vertices[faces[:, 0]], vertices[faces[:, 1]], vertices[faces[:, 2]]
    assert np.array_equal(face_areas(vertices, faces), 0.5 * np.linalg.norm(np.cross(b - a, c - a), axis=1))
    right = face_areas(np.array([[0.0, 0, 0], [3, 0, 0], [0, 4, 0]]), np.array([[0, 1, 2]]))
    assert right[0] == 6.0  # legs 3 and 4


def test_distinct_vertices_sharing_a_weighted_sum_are_not_merged():
    """(0, 0, 0) and (π, −e, 0) have the same weighted sum exactly (π·e − e·π): the exact sort
    decides, keeps both, and still merges the true duplicate."""
    assert _GENERIC[:2] == (np.e, np.pi)
    vertices = np.array([[0.0, 0, 0], [np.pi, -np.e, 0], [0, 0, 1], [1, 0, 0], [0, 0, 1]])
    faces = np.array([[0, 1, 2], [0, 3, 1], [1, 3, 4]])
    merged, merged_faces, sources = _merge_duplicate_vertices(vertices, faces)
    assert len(merged) == 4 and sorted(sources.tolist()) == [0, 1, 2, 3]
    np.testing.assert_array_equal(merged[merged_faces], vertices[faces])


@pytest.mark.parametrize("seed", range(3))
def test_distinct_faces_keep_the_first_of_each_triangle_in_any_vertex_order(seed):
    rng = np.random.default_rng(seed)
    faces = _random_faces(rng, 8, 60)  # few vertices: many repeats, in every rotation and orientation
    kept = distinct_faces(faces)
    first = {}
    for face in faces.tolist():
        first.setdefault(frozenset(face), face)
    assert kept.tolist() == list(first.values())


def test_distinct_half_edges_are_numpys_unique():
    half = np.random.default_rng(3).integers(0, 500, 300)
    np.testing.assert_array_equal(_distinct(half, 500), np.unique(half))
