"""What the correspondence network reads of a part: intrinsic, and the same however it is uploaded."""

import numpy as np
from scipy.spatial import Delaunay
from scipy.spatial.transform import Rotation

from app.contract import CORRESPONDENCE_INPUTS, HKS_TIMES
from app.geometry.descriptors import CURVATURE_SCALE_M, FEATURES, cloud_inputs, magnified, mesh_inputs
from app.geometry.topology import boundary_vertex_mask
from tests.conftest import bumpy_patch, sphere


def test_inputs_do_not_depend_on_frame_or_winding(patch):
    """Rigid motion and an inward winding change nothing the network reads (its gradients are
    taken in frames of an outward normal, so their cross products keep their sign)."""
    turn = Rotation.from_euler("zyx", [1.0, 0.3, -0.7]).as_matrix()
    reference = mesh_inputs(patch.vertices, patch.faces)
    moved = mesh_inputs(patch.vertices @ turn.T + 5.0, patch.faces[:, ::-1])
    np.testing.assert_allclose(moved.features, reference.features, atol=1e-4)
    np.testing.assert_allclose(moved.eigenvalues, reference.eigenvalues, rtol=1e-4)
    np.testing.assert_allclose(moved.mass, reference.mass, rtol=1e-5)
    np.testing.assert_array_equal(moved.stencil.neighbours, reference.stencil.neighbours)


def test_magnified_inputs_are_those_of_the_part_made_larger(patch):
    """Read magnified 1.5 times, a part's inputs are what the engine computes on the part scaled
    by 1.5 (a new solve): the same heat signature, curvature, mass, eigenvalues and gradient
    weights, and a basis spanning the same functions (each eigenvector up to its sign)."""
    scaled = mesh_inputs(1.5 * patch.vertices, patch.faces)
    read = magnified(mesh_inputs(patch.vertices, patch.faces), 1.5)
    np.testing.assert_allclose(read.features, scaled.features, atol=1e-4)
    np.testing.assert_allclose(read.eigenvalues, scaled.eigenvalues, rtol=1e-4)
    np.testing.assert_allclose(read.mass, scaled.mass, rtol=1e-5)
    np.testing.assert_allclose(read.stencil.weights, scaled.stencil.weights, rtol=1e-3, atol=1e-3)
    np.testing.assert_allclose(read.points, scaled.points, rtol=1e-6)
    overlap = np.abs(np.einsum("nk,n,nk->k", read.basis, read.mass, scaled.basis))
    assert overlap[:20].min() > 0.999


def test_boundary_flag_and_heat_signature_of_a_closed_surface():
    """A closed sphere has no boundary flag; its heat signature is the same at every vertex (up to
    the mesh), and at the smallest time near 0: 4πt·HKS = 1 + Kt/3 + … (K = 1/r², 0.03 here),
    where 64 eigenfunctions reach that time (λ₆₄·t ≈ 5 on a sphere of 15 cm)."""
    mesh = sphere(4)
    inputs = mesh_inputs(mesh.vertices * 0.15, mesh.faces)
    assert inputs.features.shape == (len(mesh.vertices), FEATURES)
    assert not inputs.features[:, -1].any()
    heat = inputs.features[:, : len(HKS_TIMES)]
    assert heat.std(axis=0).max() < 0.05
    assert abs(heat[:, 0].mean()) < 0.1
    assert len(HKS_TIMES) == FEATURES - 2


def half_cylinder(radius: float) -> tuple[np.ndarray, np.ndarray]:
    """What a camera sees of a limb: half a cylinder of ``radius``, 30 cm long."""
    angle, height = np.meshgrid(np.linspace(0, np.pi, 40), np.linspace(0, 0.3, 60))
    faces = Delaunay(np.column_stack([angle.ravel() * radius, height.ravel()])).simplices
    vertices = np.column_stack([radius * np.cos(angle.ravel()), radius * np.sin(angle.ravel()), height.ravel()])
    return vertices, faces


def test_mean_curvature_of_a_sphere_and_of_half_a_limb():
    """H = 1/r on a sphere and 1/(2r) on a cylinder, positive with the normal outward whichever
    way the file winds it, from a mesh and from its vertices as a cloud. The half cylinder is
    intrinsically flat (its heat signature reads as a flat strip's): only H tells it is round."""
    mesh = sphere(4)
    bend = {
        "mesh": mesh_inputs(mesh.vertices * 0.15, mesh.faces).features[:, -2],
        "inward": mesh_inputs(mesh.vertices * 0.15, mesh.faces[:, ::-1]).features[:, -2],
        "cloud": cloud_inputs(mesh.vertices * 0.15, None).features[:, -2],
    }
    for name, feature in bend.items():  # the cotangent formula errs ~15 % at the 12 five-valent vertices
        curvature = np.sinh(feature) / CURVATURE_SCALE_M
        np.testing.assert_allclose(np.median(curvature), 1 / 0.15, rtol=0.005, err_msg=name)
        np.testing.assert_allclose(curvature, 1 / 0.15, rtol=0.15, err_msg=name)
    vertices, faces = half_cylinder(0.04)
    for winding in (faces, faces[:, ::-1]):
        feature = mesh_inputs(vertices, winding).features[:, -2]
        inner = ~boundary_vertex_mask(winding, len(vertices))
        np.testing.assert_allclose(np.median(np.sinh(feature[inner])) / CURVATURE_SCALE_M, 1 / 0.08, rtol=0.02)


def test_boundary_flag_marks_the_boundary_and_feeds_are_named_by_the_contract():
    patch = bumpy_patch(2)
    inputs = mesh_inputs(patch.vertices, patch.faces)
    np.testing.assert_array_equal(inputs.features[:, -1] > 0, boundary_vertex_mask(patch.faces, len(patch.vertices)))
    feeds = inputs.feeds()
    assert tuple(feeds) == CORRESPONDENCE_INPUTS
    assert feeds["neighbours"].dtype == np.int64 and feeds["basis"].dtype == np.float32


def test_cloud_inputs_of_a_mesh_s_vertices_read_like_the_mesh():
    """A point cloud of a mesh's vertices has nearly the mesh's low eigenvalues (robust-laplacian's
    point-cloud operator), so the network sees one shape whichever way it arrives."""
    mesh = sphere(4)
    from_mesh = mesh_inputs(mesh.vertices, mesh.faces)
    from_cloud = cloud_inputs(mesh.vertices, None)
    np.testing.assert_allclose(from_cloud.eigenvalues[1:16], from_mesh.eigenvalues[1:16], rtol=0.05)
    assert from_cloud.faces is None and from_mesh.faces is not None
