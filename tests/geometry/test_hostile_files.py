"""Files that say one thing to the checker and another to a parser, or that a parser misreads:
each is read as the file honestly holds or refused with its problem, never a 500 and never a
plausible wrong shape (the reproducers of an independent probe, at the mechanism)."""

import numpy as np
import pytest

from app.geometry import io as geometry_io
from app.geometry.errors import TooManyVertices, UnreadableFile, library_reason
from app.geometry.io import load_shape
from app.geometry.shapes import Mesh
from harness.builders import ascii_ply, glb_of, mesh_bytes
from tests.conftest import bumpy_patch

CAP = 50_000
DIGITS = b"9" * 5000
XYZ_HEADER = b"property float x\nproperty float y\nproperty float z\n"


@pytest.fixture(scope="module")
def patch() -> Mesh:
    return bumpy_patch(seed=1, n=300)


def _read(data: bytes, file_type: str):
    return load_shape(data, file_type, max_vertices=CAP)


def _same_mesh(shape, patch: Mesh) -> None:
    assert isinstance(shape, Mesh)
    np.testing.assert_allclose(shape.vertices, patch.vertices, atol=1e-6)
    np.testing.assert_array_equal(shape.faces, patch.faces)


@pytest.mark.parametrize(
    ("data", "file_type"),
    [
        (b"ply\nformat ascii 1.0\nelement vertex " + DIGITS + b"\n" + XYZ_HEADER + b"end_header\n0 0 0\n", "ply"),
        (
            b"ply\nformat binary_little_endian 1.0\nelement vertex "
            + b"9" * 4301
            + b"\n"
            + XYZ_HEADER
            + b"end_header\n",
            "ply",
        ),
        (b"OFF\n" + DIGITS + b" 1 0\n0 0 0\n", "off"),
    ],
)
def test_a_count_of_thousands_of_digits_is_refused_before_it_is_converted(data, file_type):
    with pytest.raises(UnreadableFile, match="5000 digits|4301 digits"):
        _read(data, file_type)


def test_a_face_row_whose_count_has_thousands_of_digits_is_refused(patch):
    rows = ascii_ply(patch.vertices, patch.faces).rstrip(b"\n").split(b"\n")
    with pytest.raises(UnreadableFile):
        _read(b"\n".join([*rows[:-1], b"9" * 600 + b" 0 1 2"]) + b"\n", "ply")


def test_a_ply_is_read_by_its_format_line_not_by_a_comment(patch):
    """A comment saying 'ascii' before a binary format line: trimesh took the file as ASCII,
    the checker as binary. One reading now: binary, so an ASCII body is the wrong length."""
    header = b"ply\ncomment ascii\nformat binary_little_endian 1.0\nelement vertex 3\n" + XYZ_HEADER + b"end_header\n"
    with pytest.raises(UnreadableFile):
        _read(header + b"0 0 0\n" * 3000, "ply")
    with pytest.raises(UnreadableFile, match="one format line"):
        _read(b"ply\nformat ascii 1.0\nformat binary_little_endian 1.0\nend_header\n", "ply")


def test_comments_in_a_ply_header_are_not_read_as_keywords(patch):
    """'end_header' or a texture file named in a comment neither end the header nor are looked up."""
    plain = ascii_ply(patch.vertices, patch.faces)
    noted = plain.replace(b"format ascii 1.0\n", b"format ascii 1.0\ncomment TextureFile x.png\ncomment end_header\n")
    _same_mesh(_read(noted, "ply"), patch)


def test_blank_lines_in_an_ascii_ply_body_are_not_rows(patch):
    rows = ascii_ply(patch.vertices, patch.faces).split(b"\n")
    end = rows.index(b"end_header")
    spaced = b"\n".join([*rows[: end + 2], b"", *rows[end + 2 :]])
    _same_mesh(_read(spaced, "ply"), patch)


@pytest.mark.parametrize(
    ("data", "file_type", "error", "match"),
    [
        (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf " + b"1 2 3 " * 1000 + b"\n", "obj", UnreadableFile, "a line of"),
        (b"v 0 0 0\n" * (CAP + 10), "obj", TooManyVertices, "vertices"),
        (b"# x\n" * (8 * CAP), "obj", TooManyVertices, "lines"),
        (b"0 0 0 " * 1000 + b"\n", "xyz", UnreadableFile, "a line of"),
        (
            b"solid x\n"
            + b"facet normal 0 0 1\nouter loop\n"
            + b"vertex 0 0 0\n" * 3
            + b"endloop\nendfacet\n" * (CAP // 3 + 1),
            "stl",
            TooManyVertices,
            "ASCII STL",
        ),
    ],
)
def test_text_formats_are_budgeted_on_their_bytes_before_a_parser_runs(data, file_type, error, match):
    with pytest.raises(error, match=match):
        _read(data, file_type)


@pytest.mark.parametrize(
    ("rows", "match"),
    [
        (b"0,123 0,456 0,789\n0,1 0,2 0,3\n0,5 0,1 0,7\n", "decimal commas"),  # read as two points a row
        (b"0 0 0\n1 0 0 1\n0 1 0 1\n1 1 1 1\n", "columns changed"),  # regrouped by the first row
        (b"0 0\n1 0\n", "x, y and z"),
        ((b"0 " * 200 + b"\n") * 100, "200 columns"),  # 100 k such rows took 3 s to read before refusal
    ],
)
def test_point_rows_that_do_not_fit_are_refused_not_regrouped(rows, match):
    with pytest.raises(UnreadableFile, match=match):
        _read(rows, "xyz")


def test_point_files_written_several_honest_ways_read_the_same_points(patch):
    points = patch.vertices
    plain = b"\n".join(b"%.6f %.6f %.6f" % tuple(p) for p in points) + b"\n"
    variants = {
        "csv": b"\n".join(b"%.6f,%.6f,%.6f" % tuple(p) for p in points) + b"\n",
        "csv with names": b"x,y,z\n" + b"\n".join(b"%.6f, %.6f, %.6f" % tuple(p) for p in points) + b"\n",
        "byte-order mark": b"\xef\xbb\xbf" + plain,
        "comments": b"# scanner v2\n" + plain.replace(b"\n", b" # point\n", 3),
    }
    expected = _read(plain, "xyz").points
    for name, data in variants.items():
        np.testing.assert_allclose(_read(data, "xyz").points, expected, atol=1e-9, err_msg=name)


def test_an_obj_with_a_byte_order_mark_is_the_same_mesh(patch):
    """The mark glued to the first 'v' lost that vertex and shifted every face by one."""
    _same_mesh(_read(b"\xef\xbb\xbf" + mesh_bytes(patch, "obj"), "obj"), patch)


def test_an_off_with_a_comment_beside_its_counts_is_the_same_mesh(patch):
    lines = mesh_bytes(patch, "off").split(b"\n")
    counts = next(i for i, line in enumerate(lines) if line.strip() and line.strip()[0:1].isdigit())
    lines[counts] += b"  # vertices faces edges"
    _same_mesh(_read(b"\n".join(lines), "off"), patch)


@pytest.mark.parametrize(
    ("position", "match"),
    [
        (
            {"sparse": {"count": 1, "indices": {"bufferView": 1, "componentType": 5125}, "values": {"bufferView": 0}}},
            "sparse",
        ),
        ({"componentType": 5122, "normalized": True}, "integers"),  # KHR_mesh_quantization
    ],
)
def test_glb_storage_trimesh_misreads_is_refused(patch, position, match):
    with pytest.raises(UnreadableFile, match=match):
        _read(glb_of(patch, **position), "glb")
    _same_mesh(_read(glb_of(patch), "glb"), patch)


def test_any_reader_failure_is_the_file_s_problem(monkeypatch, patch):
    """Whatever a reader raises on bad bytes becomes UnreadableFile (a 422), never a 500."""

    def surprised(*args, **kwargs):
        raise OverflowError("a reader's surprise")

    monkeypatch.setattr(geometry_io, "check_declared", surprised)
    with pytest.raises(UnreadableFile, match="surprise"):
        _read(mesh_bytes(patch, "obj"), "obj")


def test_a_library_s_reason_says_what_without_where_it_was_built():
    exc = RuntimeError(
        "GC_SAFETY_ASSERT FAILURE from /project/deps/geometry-central/src/surface/x.cpp:123 - bad mesh\nmore"
    )
    reason = library_reason(exc)
    assert "/project" not in reason and "x.cpp" not in reason and "bad mesh" in reason and "more" not in reason
