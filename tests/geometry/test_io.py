"""Every accepted format round-trips from bytes; nothing in a file reaches outside the upload."""

import io

import numpy as np
import pytest
import trimesh

from app.geometry.errors import TooManyVertices, UnreadableFile, UnsupportedFileType
from app.geometry.io import ExternalReference, load_shape, resolve_file_type, unit_scale
from app.geometry.pipeline import SpectrumOptions, spectrum_from_bytes
from app.geometry.shapes import Mesh, PointCloud
from harness.builders import (
    ascii_ply,
    external_buffer,
    glb_with_external_buffer,
    mesh_bytes,
    npy_bytes,
    zip_of,
)

CAP = 100_000


def spectrum(data: bytes, file_type: str, **options) -> np.ndarray:
    report = spectrum_from_bytes(data, file_type, SpectrumOptions(k=10, **options))
    return np.array(report.eigenvalues)


@pytest.mark.parametrize(
    ("file_type", "kwargs"),
    [
        ("ply", {"encoding": "ascii"}),
        ("ply", {"encoding": "binary"}),
        ("obj", {}),
        ("off", {}),
        ("stl", {}),
        ("glb", {}),
    ],
)
def test_mesh_formats_round_trip_to_the_same_spectrum(patch, file_type, kwargs):
    expected = spectrum(ascii_ply(patch.vertices, patch.faces), "ply")
    got = spectrum(mesh_bytes(patch, file_type, **kwargs), file_type)
    # STL and GLB store float32 coordinates.
    np.testing.assert_allclose(got, expected, rtol=1e-5)


def test_stl_duplicate_vertices_are_merged(patch):
    stl = mesh_bytes(patch, "stl")
    loaded = load_shape(stl, "stl", max_vertices=CAP)
    assert len(loaded.vertices) == 3 * len(patch.faces)  # STL repeats every corner
    report = spectrum_from_bytes(stl, "stl", SpectrumOptions(k=5))
    assert report.vertices == len(patch.vertices)
    assert report.components_dropped == 0


def test_point_cloud_formats_round_trip(patch):
    points = patch.vertices
    as_text = "\n".join(" ".join(f"{c:.17g}" for c in p) for p in points).encode()
    for data, file_type in [(ascii_ply(points), "ply"), (as_text, "xyz"), (as_text, "txt"), (npy_bytes(points), "npy")]:
        cloud = load_shape(data, file_type, max_vertices=CAP)
        assert isinstance(cloud, PointCloud)
        np.testing.assert_allclose(cloud.points, points, rtol=1e-12)


def binary_ply(points: np.ndarray, boundary: np.ndarray) -> bytes:
    """A binary little-endian PLY point cloud with a ``boundary`` vertex property."""
    rows = np.zeros(len(points), dtype=[("x", "<f4"), ("y", "<f4"), ("z", "<f4"), ("boundary", "u1")])
    rows["x"], rows["y"], rows["z"] = points.T
    rows["boundary"] = boundary
    properties = "".join(f"property float {axis}\n" for axis in "xyz") + "property uchar boundary\n"
    header = f"ply\nformat binary_little_endian 1.0\nelement vertex {len(points)}\n{properties}end_header\n"
    return header.encode() + rows.tobytes()


@pytest.mark.parametrize("encoding", ["ascii", "binary"])
def test_ply_boundary_property_is_read(encoding):
    points = np.random.default_rng(0).standard_normal((50, 3))
    flags = np.arange(50) % 7 == 0
    data = ascii_ply(points, boundary=flags) if encoding == "ascii" else binary_ply(points, flags)
    cloud = load_shape(data, "ply", max_vertices=CAP)
    np.testing.assert_array_equal(cloud.boundary, flags)


@pytest.mark.parametrize(("units", "factor"), [("cm", 0.01), ("mm", 0.001)])
def test_units_convert_to_metres(patch, units, factor):
    in_units = Mesh(patch.vertices / factor, patch.faces)
    np.testing.assert_allclose(
        spectrum(ascii_ply(in_units.vertices, in_units.faces), "ply", units=units),
        spectrum(ascii_ply(patch.vertices, patch.faces), "ply"),
        rtol=1e-8,
    )
    assert unit_scale(units) == factor
    assert unit_scale(units, scale=2.0) == 2.0


@pytest.mark.parametrize(
    ("name", "explicit", "expected"),
    [("scan.PLY", None, "ply"), ("scan.bin", "obj", "obj"), ("points.txt", None, "txt")],
)
def test_file_type_from_extension_or_parameter(name, explicit, expected):
    assert resolve_file_type(name, explicit) == expected


@pytest.mark.parametrize("name", ["scan.zip", "scan.tar.gz", "scan.gltf", "scan", None, "x.dae"])
def test_archives_and_unknown_types_are_refused(name):
    with pytest.raises(UnsupportedFileType):
        resolve_file_type(name)


def test_glb_buffer_uri_is_never_followed(tmp_path, patch):
    target = tmp_path / "geometry.bin"
    target.write_bytes(external_buffer(patch))  # a real file the server could read
    with pytest.raises(ExternalReference):
        load_shape(glb_with_external_buffer(str(target), patch), "glb", max_vertices=CAP)


def test_obj_material_library_is_ignored(patch):
    obj = mesh_bytes(patch, "obj")
    hostile = b"mtllib /etc/passwd\nusemtl root\n" + obj
    np.testing.assert_allclose(spectrum(hostile, "obj"), spectrum(obj, "obj"), rtol=1e-12)


def test_zip_named_as_ply_does_not_parse(patch):
    with pytest.raises(UnreadableFile):
        load_shape(zip_of("a.ply", ascii_ply(patch.vertices, patch.faces)), "ply", max_vertices=CAP)


def test_ply_header_with_a_billion_vertices_is_refused_before_parsing():
    header = (
        b"ply\nformat binary_little_endian 1.0\nelement vertex 1000000000\n"
        b"property float x\nproperty float y\nproperty float z\nend_header\n"
    )
    with pytest.raises(TooManyVertices):
        load_shape(header + b"\0" * 120, "ply", max_vertices=CAP)


@pytest.mark.parametrize(
    "vertex_lines",
    [
        b"v 0\nv 0 0 0\nv 1 0 0\nv 0 1 0\n",  # one vertex of a single coordinate: trimesh keeps (n, 1)
        b"v 0\n1 2 3\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 1\n",  # and a stray line (hypothesis found it)
    ],
)
def test_an_obj_whose_vertices_are_not_triples_is_unreadable_not_a_crash(vertex_lines):
    with pytest.raises(UnreadableFile, match="not \\(x, y, z\\) triples"):
        load_shape(vertex_lines + b"f 2 3 4\n", "obj", max_vertices=CAP)


@pytest.mark.parametrize("file_type", ["ply", "obj", "off", "stl", "glb"])
def test_a_one_mesh_file_loads_as_trimesh_flattens_it(patch, file_type):
    """One untransformed mesh is taken as it is, without trimesh's flattening: the same arrays."""
    data = mesh_bytes(patch, file_type)
    flat = trimesh.load_scene(io.BytesIO(data), file_type=file_type, process=False).to_mesh()
    loaded = load_shape(data, file_type, scale=1.0, max_vertices=CAP)
    np.testing.assert_array_equal(loaded.vertices, flat.vertices)
    np.testing.assert_array_equal(loaded.faces, flat.faces)


def test_a_placed_mesh_in_a_scene_is_loaded_where_it_is_placed(patch):
    """A GLB node's transform is applied (the scene is flattened as trimesh does)."""
    scene = trimesh.Scene()
    moved = np.eye(4)
    moved[:3, 3] = [0.5, -0.2, 0.1]
    scene.add_geometry(trimesh.Trimesh(patch.vertices, patch.faces, process=False), transform=moved)
    loaded = load_shape(scene.export(file_type="glb"), "glb", scale=1.0, max_vertices=CAP)
    np.testing.assert_allclose(loaded.vertices, patch.vertices + [0.5, -0.2, 0.1], atol=1e-6)
