"""A mesh above the vertex budget is placed through its collapsed copy: every vertex takes the
place of a nearby copy vertex, the copy does not depend on the frame or the winding, and a copy
the checks refuse leaves the part placed itself. A point cloud above its budget is placed through
a fixed random share of its points, each point at its nearest kept point's place."""

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

import app.geometry.placing as placing
from app.geometry.descriptors import Places, mesh_inputs
from app.geometry.errors import InvalidGeometry
from app.geometry.laplacian import mesh_operators, point_cloud_operators
from app.geometry.placing import cloud_part, mesh_part
from app.geometry.topology import boundary_vertex_mask
from tests.conftest import bumpy_patch, sphere


def _part(mesh, most: int):
    return mesh_part(mesh.vertices, mesh.faces, mesh_operators(mesh.vertices, mesh.faces), most)


def test_a_mesh_within_the_budget_is_placed_itself():
    mesh = bumpy_patch(n=900)
    part = _part(mesh, most=len(mesh.vertices))
    assert part.source is None
    np.testing.assert_array_equal(part.inputs.features, mesh_inputs(mesh.vertices, mesh.faces).features)
    places = Places(np.ones((len(mesh.vertices), 3), np.float32), np.ones(len(mesh.vertices), np.float32), 1.0)
    assert part.expand(places) is places


def test_a_larger_mesh_is_read_through_a_copy_whose_places_its_vertices_take():
    """An icosphere of 2 562 vertices through a copy of ~600: every vertex's source is a copy
    vertex within two of the copy's mean edges, and the part keeps its own area and winding."""
    mesh = sphere(4)
    operators = mesh_operators(mesh.vertices, mesh.faces)
    part = mesh_part(mesh.vertices, mesh.faces, operators, most=600)
    copy = part.inputs
    assert 400 <= copy.vertices <= 660
    assert part.source.shape == (len(mesh.vertices),) and part.source.max() < copy.vertices
    edges = copy.points[copy.faces] - copy.points[np.roll(copy.faces, 1, axis=1)]
    mean_edge = np.linalg.norm(edges, axis=2).mean()
    assert np.linalg.norm(mesh.vertices - copy.points[part.source], axis=1).max() < 2 * mean_edge
    np.testing.assert_allclose(part.mass, operators.mass.diagonal(), rtol=1e-6)
    assert len(part.points) == len(mesh.vertices) and part.faces.shape == mesh.faces.shape
    corners = part.points[part.faces]
    normals = np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])
    assert (np.einsum("ij,ij->i", normals, corners.mean(axis=1)) > 0).all()  # away from the sphere's centre
    places = Places(copy.points.astype(np.float32), np.arange(copy.vertices, dtype=np.float32), 2.0)
    expanded = part.expand(places)
    np.testing.assert_array_equal(expanded.position, copy.points[part.source].astype(np.float32))
    np.testing.assert_array_equal(expanded.confidence, part.source.astype(np.float32))


def test_the_copy_of_a_patch_keeps_its_boundary_on_the_boundary():
    """The part's own boundary flags are its own; its boundary vertices collapse into the copy's
    boundary (quadric collapse keeps an open surface's outline)."""
    mesh = bumpy_patch(n=2500)
    part = _part(mesh, most=800)
    np.testing.assert_array_equal(part.boundary, boundary_vertex_mask(mesh.faces, len(mesh.vertices)))
    assert part.inputs.boundary[part.source[part.boundary]].mean() > 0.9


def test_the_copy_does_not_depend_on_the_frame_or_the_winding():
    """The same collapses, each vertex into the same copy vertex; the copy's vertices, placed by
    each collapse's quadric, agree to its rounding."""
    mesh = bumpy_patch(n=2500)
    turn = Rotation.from_euler("xyz", [0.3, 2.0, -1.2]).as_matrix()
    moved = mesh.vertices @ turn.T + [0.4, -1.0, 2.0]
    reference = _part(mesh, most=800)
    other = mesh_part(moved, mesh.faces[:, ::-1].copy(), mesh_operators(moved, mesh.faces), 800)
    np.testing.assert_array_equal(other.source, reference.source)
    np.testing.assert_allclose(other.inputs.eigenvalues, reference.inputs.eigenvalues, rtol=1e-3, atol=1e-3)


def test_a_collapse_record_that_does_not_number_its_copy_leaves_the_part_placed_itself(monkeypatch):
    replay = placing.fast_simplification.replay_simplification

    def off_by_one(vertices, faces, collapses):
        points, triangles, into = replay(vertices, faces, collapses)
        return points, triangles, into + 1  # the last vertex's copy vertex is past the copy's end

    monkeypatch.setattr(placing.fast_simplification, "replay_simplification", off_by_one)
    mesh = bumpy_patch(n=2500)
    part = _part(mesh, most=800)
    assert part.source is None and part.inputs.vertices == len(mesh.vertices)


def test_a_copy_the_checks_refuse_leaves_the_part_placed_itself(monkeypatch):
    def refused(*_):
        raise InvalidGeometry("a collapse that left an edge with three faces")

    monkeypatch.setattr(placing, "_collapsed", refused)
    mesh = bumpy_patch(n=2500)
    part = _part(mesh, most=800)
    assert part.source is None and part.inputs.vertices == len(mesh.vertices)


@pytest.mark.parametrize("most", [0, 499])
def test_the_service_refuses_a_budget_below_its_floor(most, monkeypatch):
    from pydantic import ValidationError

    from app.core.config import Settings

    monkeypatch.setenv("SPECTRAL_UNIONS_PLACED_VERTICES", str(most))
    with pytest.raises(ValidationError):
        Settings()


def test_a_cloud_above_the_budget_is_read_through_a_random_share_of_its_points(monkeypatch):
    """A 2 562-point sphere cloud above a budget of 600: the graph reads 600 of its points (the
    same ones every time), every point takes the place of the nearest kept point, half the kept
    points' spacing away on average, and keeps its own area and boundary flags."""
    monkeypatch.setattr(placing, "PLACED_POINTS", 600)
    points = sphere(4).vertices
    operators = point_cloud_operators(points)
    boundary = points[:, 2] > 0.9  # any flags: carried as they are
    part = cloud_part(points, boundary, operators)
    assert part.inputs.vertices == 600 and part.faces is None
    assert np.array_equal(part.source, cloud_part(points, boundary, operators).source)
    kept = part.inputs.points
    spacing = np.sqrt(4 * np.pi / 600)  # a unit sphere's area shared by the kept points
    gaps = np.linalg.norm(points - kept[part.source], axis=1)
    assert gaps.mean() < spacing / 2 and gaps.max() < 2.5 * spacing  # a random share leaves some wider gaps
    np.testing.assert_array_equal(part.boundary, boundary)
    np.testing.assert_allclose(part.mass, operators.mass.diagonal(), rtol=1e-6)
    assert cloud_part(points[:500], boundary[:500], point_cloud_operators(points[:500])).source is None
