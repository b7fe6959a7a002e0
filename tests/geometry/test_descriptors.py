"""What the correspondence network reads of a part: intrinsic, and the same however it is uploaded."""

import numpy as np
from scipy.spatial.transform import Rotation

from app.contract import CORRESPONDENCE_INPUTS, HKS_TIMES
from app.geometry.descriptors import FEATURES, cloud_inputs, mesh_inputs
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


def test_boundary_flag_and_heat_signature_of_a_closed_surface():
    """A closed sphere has no boundary flag; its heat signature is the same at every vertex (up to
    the mesh), and at the smallest time near 0: 4πt·HKS = 1 + Kt/3 + … (K = 1/r², 0.03 here),
    where 64 eigenfunctions reach that time (λ₆₄·t ≈ 5 on a sphere of 15 cm)."""
    mesh = sphere(4)
    inputs = mesh_inputs(mesh.vertices * 0.15, mesh.faces)
    assert inputs.features.shape == (len(mesh.vertices), FEATURES)
    assert not inputs.features[:, -1].any()
    heat = inputs.features[:, :-1]
    assert heat.std(axis=0).max() < 0.05
    assert abs(heat[:, 0].mean()) < 0.1
    assert len(HKS_TIMES) == FEATURES - 1


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
