"""``vectors=true``: the eigenfunctions, checked against the operators themselves (S φ = λ M φ,
φᵀ M φ = I, zero on the Dirichlet boundary), and the vertex indices against what cleaning did."""

import io
import json

import numpy as np
from typer.testing import CliRunner

from app.cli import cli
from app.geometry.laplacian import mesh_operators
from app.geometry.shapes import Mesh
from app.geometry.topology import boundary_vertex_mask
from harness.builders import mesh_bytes
from tests.api.test_spectrum_api import assert_problem, post
from tests.conftest import bumpy_patch, grid

K = 8


def _arrays(response) -> dict[str, np.ndarray]:
    assert response.status_code == 200, response.text
    assert response.headers["content-type"] == "application/x-npz"
    with np.load(io.BytesIO(response.content), allow_pickle=False) as archive:
        return {name: archive[name] for name in archive.files}


def test_the_eigenfunctions_solve_the_pencil_and_are_mass_orthonormal(client):
    patch = bumpy_patch(seed=3, n=600)
    body = mesh_bytes(patch, "ply")
    arrays = _arrays(post(client, "patch.ply", body, k=K, vectors=True))
    plain = post(client, "patch.ply", body, k=K).json()
    np.testing.assert_allclose(arrays["eigenvalues"], plain["eigenvalues"], rtol=1e-10)
    np.testing.assert_array_equal(json.loads(str(arrays["report"]))["eigenvalues"], arrays["eigenvalues"])
    np.testing.assert_array_equal(arrays["vertex_indices"], np.arange(len(patch.vertices)))  # a clean mesh
    vertices = patch.vertices[arrays["vertex_indices"]].astype(np.float32).astype(np.float64)  # as PLY stores
    stiffness, mass = mesh_operators(vertices, patch.faces)
    phi, lam = arrays["eigenfunctions"], arrays["eigenvalues"]
    boundary = boundary_vertex_mask(patch.faces, len(vertices))
    assert np.abs(phi[boundary]).max() == 0.0
    free = ~boundary
    residual = (stiffness @ phi - (mass @ phi) * lam)[free]
    assert np.abs(residual).max() < 1e-6 * lam.max() * np.abs(mass @ phi).max()
    np.testing.assert_allclose(phi.T @ (mass @ phi), np.eye(K), atol=1e-8)


def test_vertex_indices_name_the_uploaded_vertices_after_cleaning(client):
    patch = bumpy_patch(seed=3, n=600)
    stray = np.array([[9.0, 9.0, 9.0]])  # unreferenced: dropped before the solve
    mesh = Mesh(np.r_[stray, patch.vertices], patch.faces + 1)
    indices = _arrays(post(client, "patch.ply", mesh_bytes(mesh, "ply"), k=K, vectors=True))["vertex_indices"]
    np.testing.assert_array_equal(indices, np.arange(1, len(patch.vertices) + 1))


def test_eigenfunctions_past_the_size_bound_are_refused(client):
    patch = bumpy_patch(seed=3, n=40_000)  # ~31 k vertices × k = 200 > 5 000 000 values
    response = post(client, "big.ply", mesh_bytes(patch, "ply"), k=200, vectors=True)
    assert "ask for fewer eigenvalues" in assert_problem(response, 422, "invalid-geometry")["detail"]


def test_the_cli_writes_the_same_eigenfunctions(client, tmp_path):
    patch = bumpy_patch(seed=3, n=600)
    path, target = tmp_path / "patch.ply", tmp_path / "functions.npz"
    path.write_bytes(mesh_bytes(patch, "ply"))
    result = CliRunner().invoke(cli, ["spectrum", str(path), "--k", str(K), "--vectors", str(target)])
    assert result.exit_code == 0, result.output
    over_http = _arrays(post(client, "patch.ply", path.read_bytes(), k=K, vectors=True))
    with np.load(target, allow_pickle=False) as written:
        np.testing.assert_allclose(np.abs(written["eigenfunctions"]), np.abs(over_http["eigenfunctions"]), atol=1e-9)
        np.testing.assert_array_equal(written["vertex_indices"], over_http["vertex_indices"])


def test_a_filled_pin_holes_centre_has_no_uploaded_vertex(client):
    plate = grid(1.0, 1.0, 20, 20)
    holed = Mesh(plate.vertices, np.delete(plate.faces, 210, axis=0))  # one interior triangle missing
    response = post(client, "holed.ply", mesh_bytes(holed, "ply"), k=K, vectors=True)
    arrays = _arrays(response)
    assert json.loads(str(arrays["report"]))["holes_filled"] == 1
    np.testing.assert_array_equal(arrays["vertex_indices"], np.r_[np.arange(len(plate.vertices)), -1])
