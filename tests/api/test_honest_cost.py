"""Uploads that are cheap to send and were dear to serve: a request costs what it honestly holds.

Each file here is small (under the 2 MB cap of the test app) and used to hold a solver worker
for seconds to minutes, or to be read as another mesh than the one it declares. Now a repair
that leaves the surface as it is (repeated faces) is solved as the surface, and a file that
lies about its size or contents is refused with its problem before it is expanded. The solve
deadline is 10 s here, so a regression fails in seconds, not after the default 120 s.
"""

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.geometry.declared import MAX_SCENE_NODES
from app.geometry.validate import MAX_FACES_PER_EDGE
from app.main import create_app
from harness.builders import ascii_ply, instanced_glb, mesh_bytes
from tests.api.conftest import settings_for
from tests.api.test_spectrum_api import assert_problem, post
from tests.conftest import bumpy_patch, disk, sphere


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    settings = settings_for(tmp_path_factory.mktemp("db") / "shapes.sqlite").model_copy(
        update={"solve_timeout_seconds": 10.0}
    )
    with TestClient(create_app(settings)) as test_client:
        yield test_client


@pytest.fixture(scope="module")
def plate():
    return disk(rings=12)


def _eigenvalues(client, name: str, data: bytes) -> dict:
    response = post(client, name, data)
    assert response.status_code == 200, response.text
    return response.json()


def test_repeated_faces_are_dropped_and_the_spectrum_is_the_surfaces(client, plate):
    """100 000 copies of one triangle (1.3 MB) held a worker for the whole deadline and changed λ₁."""
    alone = _eigenvalues(client, "plate.ply", mesh_bytes(plate, "ply"))
    copies = np.repeat(plate.faces[:1], 100_000, axis=0)
    flipped = plate.faces[:50, ::-1]  # the same triangles, the other way round
    faces = np.concatenate([plate.faces, copies, flipped])
    body = _eigenvalues(client, "padded.ply", mesh_bytes(type(plate)(plate.vertices, faces), "ply"))
    assert body["faces_dropped"] == 100_050
    assert alone["faces_dropped"] == 0
    np.testing.assert_allclose(body["eigenvalues"], alone["eigenvalues"], rtol=1e-9)


def test_an_edge_under_thousands_of_fins_is_not_a_surface(client, plate):
    """20 000 distinct triangles on one edge of a disk took robust-laplacian 8 s."""
    a, b = plate.faces[0, :2]
    fins = 20_000
    rng = np.random.default_rng(0)
    apexes = (plate.vertices[a] + plate.vertices[b]) / 2 + rng.normal(0, 0.01, (fins, 3)) + [0, 0, 0.05]
    faces = np.c_[np.full(fins, a), np.full(fins, b), len(plate.vertices) + np.arange(fins)]
    mesh = type(plate)(np.concatenate([plate.vertices, apexes]), np.concatenate([plate.faces, faces]))
    detail = assert_problem(post(client, "fins.ply", mesh_bytes(mesh, "ply")), 422, "invalid-geometry")["detail"]
    assert f"{fins + 1} faces" in detail


def test_a_few_non_manifold_edges_are_still_solved(client, plate):
    """A scan's occasional non-manifold edge (three or four faces) is within the bound."""
    a, b = plate.faces[0, :2]
    apex = (plate.vertices[a] + plate.vertices[b]) / 2 + [0, 0, 0.1]
    fins = np.array([[a, b, len(plate.vertices)]] * 1)
    mesh = type(plate)(np.r_[plate.vertices, [apex]], np.r_[plate.faces, fins])
    assert MAX_FACES_PER_EDGE >= 3
    assert len(_eigenvalues(client, "fin.ply", mesh_bytes(mesh, "ply"))["eigenvalues"]) == 20


def test_a_scene_of_thousands_of_instances_is_refused_before_it_is_read(client):
    """30 000 nodes instancing one mesh (1.4 MB) ran 24 s to the memory cap."""
    body = instanced_glb(sphere(subdivisions=1), 30_000)
    assert len(body) < 2_000_000
    detail = assert_problem(post(client, "nodes.glb", body), 422, "scene-too-large")["detail"]
    assert f"at most {MAX_SCENE_NODES}" in detail


def test_instances_are_counted_against_the_vertex_cap_before_they_are_flattened(client):
    body = instanced_glb(sphere(subdivisions=4), 40)  # 2 562 vertices each; 40 pass the cap of 50 000
    detail = assert_problem(post(client, "copies.glb", body), 422, "too-many-vertices")["detail"]
    assert "instances hold 102480 vertices" in detail


def test_a_ply_body_longer_than_its_header_is_refused(client):
    """An ASCII PLY of a valid patch followed by 250 000 more lines was parsed whole and its tail
    ignored (15 M such lines took 42 s)."""
    patch = bumpy_patch(seed=1, n=300)
    body = ascii_ply(patch.vertices, patch.faces) + b"0 0 0\n" * 250_000
    detail = assert_problem(post(client, "long.ply", body), 422, "unreadable-file")["detail"]
    assert "data lines but the file holds" in detail


def test_a_ply_header_declaring_more_faces_than_the_cap_is_refused(client):
    header = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    header += b"element face 900000000\nproperty list uchar int vertex_indices\nend_header\n"
    assert_problem(post(client, "faces.ply", header + b"0 0 0\n" * 3), 422, "too-many-faces")


@pytest.mark.parametrize(
    ("row", "what"),
    [
        (b"3 0 1.5 2", "whole numbers"),  # trimesh truncated the index to 1
        (b"-3 0 1 2", "lists -3 vertices"),  # trimesh dropped the face silently
        (b"1099511627776 0 1 2", "lists 1099511627776 vertices"),
        (b"3 0 1", "with 2 indices"),
    ],
)
def test_a_broken_ply_face_row_is_refused(client, row, what):
    patch = bumpy_patch(seed=1, n=300)
    good = ascii_ply(patch.vertices, patch.faces).rstrip(b"\n").split(b"\n")
    broken = b"\n".join(good[:-1] + [row]) + b"\n"
    detail = assert_problem(post(client, "row.ply", broken), 422, "unreadable-file")["detail"]
    assert what in detail


def test_an_off_with_fewer_vertices_than_declared_is_refused(client):
    patch = bumpy_patch(seed=1, n=300)
    text = mesh_bytes(patch, "off").decode()
    first, counts, *rest = text.splitlines()
    nv, nf, ne = (int(c) for c in counts.split())
    short = "\n".join([first, f"{nv + 50} {nf} {ne}", *rest]) + "\n"  # the header claims 50 more vertices
    detail = assert_problem(post(client, "short.off", short.encode()), 422, "unreadable-file")["detail"]
    assert "data lines but the file holds" in detail


def test_an_obj_face_index_zero_is_refused(client):
    """OBJ counts vertices from 1; trimesh read index 0 as the last vertex."""
    patch = bumpy_patch(seed=1, n=300)
    text = mesh_bytes(patch, "obj").decode() + "f 0 1 2\n"
    detail = assert_problem(post(client, "zero.obj", text.encode()), 422, "unreadable-file")["detail"]
    assert "index 0" in detail


def test_a_text_cloud_with_more_lines_than_the_cap_is_refused_before_parsing(client):
    body = b"0 0 0\n" * 60_000  # the test app's cap is 50 000 points
    assert_problem(post(client, "many.xyz", body, closed=True), 422, "too-many-vertices")


def test_honest_files_of_every_text_format_are_still_read(client):
    """The checks scan what the exporters write, trailing blank lines included."""
    patch = bumpy_patch(seed=1, n=300)
    spectra = [
        _eigenvalues(client, f"patch.{kind}", mesh_bytes(patch, kind, **options))["eigenvalues"]
        for kind, options in [("ply", {"encoding": "ascii"}), ("ply", {}), ("off", {}), ("obj", {})]
    ]
    commented = mesh_bytes(patch, "off") + b"\n\n"
    spectra.append(_eigenvalues(client, "noted.off", commented)["eigenvalues"])
    for other in spectra[1:]:
        np.testing.assert_allclose(other, spectra[0], rtol=1e-5)
