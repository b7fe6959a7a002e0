"""Tangent-plane gradients, outward winding and cloud normals against analytic truths."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from app.geometry.laplacian import mesh_operators, point_cloud_operators
from app.geometry.tangent import (
    cloud_neighbours,
    cloud_normals,
    consistently_wound,
    gradient_stencil,
    mesh_neighbours,
    outward_faces,
    vertex_normals,
)
from app.geometry.topology import boundary_vertex_mask, drop_unreferenced, largest_component
from app.inference.template import Template
from tests.conftest import bumpy_patch, disk, grid, sphere


def _gradients(points, faces, fields):
    """Each field's stencil gradient (n, 2) in the frames of the mesh as wound."""
    stencil = gradient_stencil(points, vertex_normals(points, faces), mesh_neighbours(faces, len(points), points))
    change = fields[stencil.neighbours] - fields[:, None]  # (n, K, fields)
    return np.einsum("nkc,nkd->ncd", change, stencil.weights.astype(np.float64))  # (n, fields, 2)


def test_linear_fields_have_exact_gradients_and_the_normal_fixes_their_handedness():
    """On a flat grid, f = x and g = y have unit gradients at right angles: (∇f × ∇g)·N is +1
    with the normal up and −1 with the faces turned over. That sign is what the network reads
    left from right by; the frames' own turn does not change it."""
    mesh = grid(1.0, 1.0, 12, 12)
    inside = ~boundary_vertex_mask(mesh.faces, len(mesh.vertices))
    fields = mesh.vertices[:, :2]
    for faces, sign in ((mesh.faces, 1.0), (mesh.faces[:, ::-1], -1.0)):
        g = _gradients(mesh.vertices, faces, fields)[inside]
        np.testing.assert_allclose(np.linalg.norm(g, axis=2), 1.0, atol=1e-4)
        cross = g[:, 0, 0] * g[:, 1, 1] - g[:, 0, 1] * g[:, 1, 0]
        np.testing.assert_allclose(cross, sign, atol=1e-4)


def test_gradient_of_height_on_the_sphere_matches_its_tangent_projection():
    """|∇z| on the unit sphere is √(1 − z²) (the tangent part of the up direction)."""
    mesh = sphere(4)
    z = mesh.vertices[:, 2:3]
    g = _gradients(mesh.vertices, mesh.faces, z)[:, 0]
    np.testing.assert_allclose(np.linalg.norm(g, axis=1), np.sqrt(1 - z[:, 0] ** 2), atol=0.02)


def test_gradient_magnitudes_do_not_depend_on_rigid_motion():
    mesh = bumpy_patch(3)
    turn = Rotation.from_euler("xyz", [0.4, -1.1, 2.0]).as_matrix()
    moved = mesh.vertices @ turn.T + np.array([3.0, -2.0, 0.5])
    field = np.sin(3 * mesh.vertices[:, :1]) + mesh.vertices[:, 1:2] ** 2
    before = np.linalg.norm(_gradients(mesh.vertices, mesh.faces, field), axis=2)
    after = np.linalg.norm(_gradients(moved, mesh.faces, field), axis=2)
    np.testing.assert_allclose(after, before, atol=1e-9)


@pytest.mark.parametrize("make", [lambda: sphere(3), lambda: disk(1.0, 12), lambda: bumpy_patch(1)])
def test_outward_faces_turn_an_inward_part_and_keep_an_outward_one(make):
    """A part uploaded with inward normals is turned: both windings give the same faces."""
    mesh = make()
    vertices = mesh.vertices.copy()
    vertices[:, 2] += 0.2 * (1 - (vertices[:, :2] ** 2).sum(axis=1))  # a dome: its outside is up
    stiffness = mesh_operators(vertices, mesh.faces).stiffness
    outward = outward_faces(vertices, mesh.faces, stiffness)
    np.testing.assert_array_equal(outward_faces(vertices, mesh.faces[:, ::-1], stiffness), outward)
    centre = vertices.mean(axis=0)
    normals = vertex_normals(vertices, outward)
    assert np.mean(np.einsum("ij,ij->i", normals, vertices - centre + [0, 0, 1e-3]) > 0) > 0.9


def test_a_soup_with_flipped_faces_is_wound_consistently():
    mesh = sphere(2)
    faces = mesh.faces.copy()
    faces[::3] = faces[::3, ::-1]
    assert not consistently_wound(faces)
    mended = outward_faces(mesh.vertices, faces, mesh_operators(mesh.vertices, mesh.faces).stiffness)
    assert consistently_wound(mended)
    normals = vertex_normals(mesh.vertices, mended)
    assert np.all(np.einsum("ij,ij->i", normals, mesh.vertices) > 0)


def test_cloud_normals_of_a_sphere_point_outward():
    points = sphere(3).vertices
    normals = cloud_normals(points, cloud_neighbours(points), point_cloud_operators(points).stiffness)
    np.testing.assert_allclose(np.einsum("ij,ij->i", normals, points), 1.0, atol=0.02)


TEMPLATE = Template.load(Path(__file__).resolve().parents[2] / "models")
VIEWS = [(0, -1, 0), (0, 1, 0), (1, 0, 0), (-1, 0, 0), (0.6, -0.8, 0.3), (-0.5, 0.5, -0.7)]


def _view_of_the_template(direction) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """What a camera far along ``direction`` roughly sees of the template body (faces facing it,
    the largest piece): vertices, faces wound as the body's, and each vertex's outward normal
    as the closed body gives it."""
    vertices, faces = TEMPLATE.vertices, TEMPLATE.faces
    a, b, c = (vertices[faces[:, i]] for i in range(3))
    facing = np.cross(b - a, c - a) @ np.asarray(direction, float) > 0
    kept, _ = largest_component(vertices, faces[facing])
    normals = vertex_normals(vertices, faces)
    used = np.unique(kept)
    view, view_faces = drop_unreferenced(vertices, kept)
    return view, view_faces, normals[used]


def test_the_template_body_is_wound_outward():
    """The truth the views below are held to: the closed template encloses a positive volume."""
    a, b, c = (TEMPLATE.vertices[TEMPLATE.faces[:, i]] for i in range(3))
    assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() > 0


@pytest.mark.parametrize("direction", VIEWS)
def test_a_camera_view_of_a_body_faces_outward_as_a_mesh_and_as_a_cloud(direction):
    """An open view of a body, either winding, and its vertices as a point cloud: every normal
    points to the side the body's own outward normals do (a view's side "away from its
    centroid" is wrong for most views of a standing body)."""
    vertices, faces, truth = _view_of_the_template(direction)
    stiffness = mesh_operators(vertices, faces).stiffness
    for wound in (faces, faces[:, ::-1]):
        normals = vertex_normals(vertices, outward_faces(vertices, wound, stiffness))
        assert np.mean(np.einsum("ij,ij->i", normals, truth) > 0) > 0.99
    normals = cloud_normals(vertices, cloud_neighbours(vertices), point_cloud_operators(vertices).stiffness)
    assert np.mean(np.einsum("ij,ij->i", normals, truth) > 0) > 0.95


def test_a_wide_one_ring_is_cut_to_its_nearest_members():
    """A fan's centre has as many neighbours as its loop: the stencil keeps the nearest."""
    count = 40
    angle = 2 * np.pi * np.arange(count) / count
    radius = 1.0 + 0.5 * (np.arange(count) % 2)
    vertices = np.vstack(
        [[0, 0, 0], np.column_stack([radius * np.cos(angle), radius * np.sin(angle), np.zeros(count)])]
    )
    faces = np.column_stack([np.zeros(count, int), 1 + np.arange(count), 1 + (np.arange(count) + 1) % count])
    table = mesh_neighbours(faces, len(vertices), vertices)
    assert table.shape[1] == 12
    assert set(table[0]) <= set(1 + np.flatnonzero(radius == 1.0))
