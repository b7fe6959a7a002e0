"""What a text or PLY file declares, checked against what it holds, before a parser expands it.

A parser's cost follows what the file says, not what it honestly contains: an ASCII PLY that
declares three vertices and then carries millions of lines held trimesh for tens of seconds, an OFF with
fewer vertices than its header names was read as a different mesh, and trimesh reads a PLY
face index of 1.5 as 1, an OBJ index 0 (OBJ counts from 1) as the last vertex, and a list
count of −3 as no face at all. Each check here is a scan of the bytes (no parse), so a file
that lies about itself is refused in milliseconds and a file that does not is read as before.

The parser then reads what was checked, not its own reading of the same bytes:
:func:`check_declared` returns the bytes to parse (a PLY's header rebuilt from the lines that
were checked, its ASCII body from the rows that were counted; a text file without its
byte-order mark). Every count is bounded by its length before it is converted.
"""

import json
import re
import struct
from dataclasses import dataclass

import numpy as np

from app.geometry.errors import SceneTooLarge, TooManyFaces, TooManyVertices, UnreadableFile
from app.geometry.formats import TEXT_TYPES

# A closed triangle mesh has about two faces per vertex; four leaves room for meshes whose
# vertices are split at seams, and still bounds what a face list can cost.
FACES_PER_VERTEX = 4
MAX_POLYGON_SIDES = 64  # a polygon is fanned into triangles; scanners write triangles and quads
HEADER_BYTES = 65536
MAX_SCENE_NODES = 1000  # a scan is a mesh or a few; tens of thousands of nodes are slow just to read
SPARE_LINES = 64  # blank and comment lines tolerated beyond the declared rows, not millions of them
MAX_COUNT_DIGITS = 10  # a longer count is past every cap; Python refuses int() past 4 300 digits
# The longest line a text format's honest rows need: a 64-sided OBJ face of v/vt/vn triples, a
# PLY row of a few dozen properties; a point row is x y z and a few attributes.
MAX_MESH_LINE_BYTES = 4096
MAX_POINT_LINE_BYTES = 512
# Lines an OBJ may hold per vertex of the cap (v, vt and vn lines) beyond its faces.
OBJ_LINES_PER_VERTEX = 3
STL_BINARY_HEADER, STL_BINARY_FACET = 84, 50
GLTF_FLOAT = 5126  # glTF componentType of 32-bit floats
UTF8_BOM = b"\xef\xbb\xbf"

_PLY_FORMAT = re.compile(rb"format[ \t]+(ascii|binary_little_endian|binary_big_endian)[ \t]+1\.0")
_PLY_PROPERTY = re.compile(rb"property[ \t]+(?:list[ \t]+\S+[ \t]+)?\S+[ \t]+\S+")
_PLY_IGNORED = (b"comment", b"obj_info")
_PLY_END = re.compile(rb"^end_header[ \t]*\r?\n", re.MULTILINE)
_OBJ_VERTEX = re.compile(rb"^[ \t]*v[ \t]", re.MULTILINE)
_OBJ_FACE = re.compile(rb"^[ \t]*f[ \t]", re.MULTILINE)
_OFF_COUNTS = re.compile(rb"\A\s*(?:#[^\n]*\n\s*)*[CN]?OFF\s+(?:#[^\n]*\n\s*)*(\d+)\s+(\d+)\s+\d+", re.DOTALL)
_OBJ_ZERO_INDEX = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[ \t])-?0+(?=[/ \t\r\n]|$)", re.MULTILINE)
_NOT_INTEGERS = re.compile(rb"[^0-9 \t\r\n-]")


@dataclass(frozen=True)
class PlyHeader:
    """The parts of a PLY header that say how much data follows."""

    ascii: bool
    elements: list[tuple[str, int]]  # in file order
    body_start: int  # offset of the first data byte
    lines: list[bytes]  # the header as the parser is to read it: ply, format, elements and properties


def max_faces(max_vertices: int) -> int:
    """The face cap that goes with a vertex cap."""
    return FACES_PER_VERTEX * max_vertices


def require_within_caps(vertices: int, faces: int, max_vertices: int, what: str) -> None:
    """Refuse ``vertices`` over the cap or ``faces`` over the face cap; ``what`` says whose
    counts they are ("the PLY header declares", "the scene's instances hold")."""
    if vertices > max_vertices:
        raise TooManyVertices(f"{what} {vertices} vertices; the cap is {max_vertices}")
    if faces > max_faces(max_vertices):
        raise TooManyFaces(f"{what} {faces} faces; the cap is {max_faces(max_vertices)}")


def count_of(token: bytes, what: str) -> int:
    """A declared count as an integer: whole digits, and no longer than any cap could need
    (:data:`MAX_COUNT_DIGITS`), so converting it costs nothing and never fails."""
    if not token.isdigit():
        raise UnreadableFile(f"{what} {token[:20].decode(errors='replace')!r}, not a whole number")
    if len(token) > MAX_COUNT_DIGITS:
        raise UnreadableFile(f"{what} a count of {len(token)} digits, past every cap")
    return int(token)


def check_declared(data: bytes, file_type: str, max_vertices: int) -> bytes:
    """Refuse a file whose declared or actual size exceeds the caps, or whose body is not what
    its header declares, before it is parsed; return the bytes the parser is to read (see the
    module docstring)."""
    if file_type in TEXT_TYPES:
        data = data.removeprefix(UTF8_BOM)
    if file_type == "ply":
        return _checked_ply(data, max_vertices)
    if file_type == "off":
        return _checked_off(data, max_vertices)
    if file_type == "obj":
        _check_obj(data, max_vertices)
    elif file_type == "stl":
        _check_stl(data, max_vertices)
    elif file_type == "glb":
        _check_glb(data)
    elif file_type in ("xyz", "txt"):
        _check_line_budget(data, max_vertices)
    return data


def parse_ply_header(data: bytes) -> PlyHeader:
    """The format, element counts and data offset of a PLY, or :class:`UnreadableFile`. The
    header must say one thing to every reader: one format line, elements and properties, and
    comments (dropped from :attr:`PlyHeader.lines`, so no reader finds keywords in them)."""
    end = _PLY_END.search(data, 0, HEADER_BYTES)
    if not data.startswith(b"ply") or end is None:
        raise UnreadableFile(f"not a PLY file: no 'ply' magic or no end_header in its first {HEADER_BYTES} bytes")
    raw = [line.strip() for line in data[: end.start()].split(b"\n")[1:]]
    formats = [line for line in raw if line.startswith(b"format")]
    if len(formats) != 1 or not _PLY_FORMAT.fullmatch(formats[0]):
        raise UnreadableFile(
            "the PLY header needs one format line: 'format ascii|binary_little_endian|binary_big_endian 1.0'"
        )
    lines, elements = [b"ply", formats[0]], []
    for line in raw:
        if not line or line.startswith(_PLY_IGNORED) or line is formats[0]:
            continue
        tokens = line.split()
        if tokens[0] == b"element" and len(tokens) == 3:
            name = tokens[1].decode(errors="replace")
            elements.append((name, count_of(tokens[2], f"the PLY element {name!r} has")))
        elif not (elements and _PLY_PROPERTY.fullmatch(line)):
            raise UnreadableFile(
                f"the PLY header line {line[:40].decode(errors='replace')!r} is not an element or property"
            )
        lines.append(line)
    return PlyHeader(formats[0].split()[1] == b"ascii", elements, end.end(), lines)


def _checked_ply(data: bytes, max_vertices: int) -> bytes:
    header = parse_ply_header(data)
    counts = dict(header.elements)
    require_within_caps(counts.get("vertex", 0), counts.get("face", 0), max_vertices, "the PLY header declares")
    body = data[header.body_start :]
    if header.ascii:
        body = b"\n".join(_checked_ascii_ply_rows(body, header.elements)) + b"\n"
    return b"\n".join([*header.lines, b"end_header"]) + b"\n" + body


def _checked_ascii_ply_rows(body: bytes, elements: list[tuple[str, int]]) -> list[bytes]:
    """One row per declared element, and face rows of whole indices with sane list counts."""
    declared = sum(count for _, count in elements)
    _require_short_lines(body, MAX_MESH_LINE_BYTES, "PLY")
    lines = _data_lines(body, declared, "the PLY header declares")
    start = 0
    for name, count in elements:
        if name == "face":
            _check_face_rows(lines[start : start + count])
        start += count
    return lines


def _data_lines(body: bytes, declared: int, what: str) -> list[bytes]:
    """The body's data lines (not blank, not a comment), refused when they are more or fewer
    than declared. The newlines are counted before the body is split, so the split is bounded."""
    held = body.count(b"\n") + 1
    if held > declared + SPARE_LINES:
        raise UnreadableFile(f"{what} {declared} data lines but the file holds {held}")
    lines = [line for line in body.splitlines() if line.strip() and not line.lstrip().startswith(b"#")]
    if len(lines) != declared:
        raise UnreadableFile(f"{what} {declared} data lines but the file holds {len(lines)}")
    return lines


def _check_face_rows(rows: list[bytes]) -> None:
    if not rows:
        return
    if _NOT_INTEGERS.search(b"\n".join(rows)):
        raise UnreadableFile("PLY face rows must hold whole numbers only (vertex indices are integers)")
    for index, row in enumerate(rows):
        tokens = row.split()
        sides = int(tokens[0]) if len(tokens[0]) <= MAX_COUNT_DIGITS else MAX_POLYGON_SIDES + 1
        if not 3 <= sides <= MAX_POLYGON_SIDES or len(tokens) < 1 + sides:
            raise UnreadableFile(
                f"PLY face {index} lists {tokens[0][:20].decode()} vertices with {len(tokens) - 1} indices "
                f"(a face has 3 to {MAX_POLYGON_SIDES})"
            )


def _checked_off(data: bytes, max_vertices: int) -> bytes:
    """The counts within the caps and as many data rows as they declare; the file rebuilt from
    them (comments, also one beside the counts, are the checker's to skip, not the parser's)."""
    counts = _OFF_COUNTS.match(data[:HEADER_BYTES])
    if counts is None:
        raise UnreadableFile("not an OFF file: no OFF keyword followed by vertex, face and edge counts")
    vertices = count_of(counts.group(1), "the OFF header declares")
    faces = count_of(counts.group(2), "the OFF header declares")
    require_within_caps(vertices, faces, max_vertices, "the OFF header declares")
    _require_short_lines(data, MAX_MESH_LINE_BYTES, "OFF")
    rows = _data_lines(data[counts.end() :], vertices + faces, "the OFF header declares")
    return b"\n".join([b"OFF", b"%d %d 0" % (vertices, faces), *rows]) + b"\n"


def _check_obj(data: bytes, max_vertices: int) -> None:
    """Lines within what the caps allow (counted before they are found), no line longer than a
    face can be, vertex and face lines within the caps, no face index 0."""
    budget = OBJ_LINES_PER_VERTEX * max_vertices + max_faces(max_vertices) + SPARE_LINES
    lines = data.count(b"\n")
    if lines > budget:
        raise TooManyVertices(f"the OBJ holds {lines} lines, more than the caps allow ({budget})")
    _require_short_lines(data, MAX_MESH_LINE_BYTES, "OBJ")
    vertices, faces = len(_OBJ_VERTEX.findall(data)), len(_OBJ_FACE.findall(data))
    require_within_caps(vertices, faces, max_vertices, "the OBJ holds")
    if _OBJ_ZERO_INDEX.search(data):
        raise UnreadableFile("an OBJ face uses vertex index 0; OBJ indices start at 1 (or count back from -1)")


def _check_stl(data: bytes, max_vertices: int) -> None:
    """A binary STL's facet count agrees with its length; an ASCII STL's facets are counted.
    Each facet is three vertices of its own."""
    if len(data) >= STL_BINARY_HEADER:
        (declared,) = struct.unpack_from("<I", data, 80)
        if STL_BINARY_HEADER + STL_BINARY_FACET * declared == len(data):
            require_within_caps(3 * declared, declared, max_vertices, "the binary STL declares")
            return
    facets = data.count(b"endfacet")
    require_within_caps(3 * facets, facets, max_vertices, "the ASCII STL holds")
    _require_short_lines(data, MAX_MESH_LINE_BYTES, "STL")
    lines = data.count(b"\n")
    if lines > 7 * facets + SPARE_LINES:  # facet, outer loop, 3 vertices, endloop, endfacet
        raise UnreadableFile(f"the ASCII STL holds {lines} lines for {facets} facets")


def _require_short_lines(data: bytes, limit: int, kind: str) -> None:
    """Refuse a line longer than ``limit`` bytes: one line of millions of tokens took parsers
    seconds to split. Found with one vectorized pass over the newlines."""
    ends = np.flatnonzero(np.frombuffer(data, np.uint8) == ord("\n"))
    longest = int(np.diff(ends, prepend=-1, append=len(data)).max()) - 1 if len(data) else 0
    if longest > limit:
        raise UnreadableFile(f"the {kind} file has a line of {longest} bytes; its rows take at most {limit}")


def _check_glb(data: bytes) -> None:
    """Count the scene's nodes in the GLB's JSON chunk before trimesh builds its scene graph."""
    try:
        magic, _, _, length, kind = struct.unpack_from("<4sIIII", data)
        document = json.loads(data[20 : 20 + length]) if magic == b"glTF" and kind == 0x4E4F534A else None
    except (struct.error, ValueError, RecursionError) as exc:
        raise UnreadableFile(f"not a GLB file: its JSON chunk cannot be read ({type(exc).__name__})") from exc
    if not isinstance(document, dict):
        raise UnreadableFile("not a GLB file: no glTF magic followed by a JSON chunk holding an object")
    nodes = document.get("nodes", [])
    if isinstance(nodes, list) and len(nodes) > MAX_SCENE_NODES:
        raise SceneTooLarge(f"the GLB scene has {len(nodes)} nodes; at most {MAX_SCENE_NODES} are accepted")
    _check_glb_accessors(document)


def _check_glb_accessors(document: dict) -> None:
    """Refuse what trimesh would misread: sparse accessors (it reads their dense base and drops
    the sparse values) and positions stored as integers (KHR_mesh_quantization: it reads the
    integers as metres, ignoring normalization)."""
    listed = document.get("accessors", [])
    accessors = [a if isinstance(a, dict) else {} for a in listed] if isinstance(listed, list) else []
    if any("sparse" in accessor for accessor in accessors):
        raise UnreadableFile("the GLB stores accessors sparsely, which is not read here; export them dense")
    for index in _glb_position_accessors(document):
        if 0 <= index < len(accessors) and accessors[index].get("componentType") != GLTF_FLOAT:
            raise UnreadableFile(
                "the GLB stores vertex positions as integers (quantized), not read here; export them as floats"
            )


def _glb_position_accessors(document: dict) -> set[int]:
    meshes = document.get("meshes", [])
    found = set()
    for mesh in meshes if isinstance(meshes, list) else []:
        primitives = mesh.get("primitives", []) if isinstance(mesh, dict) else []
        for primitive in primitives if isinstance(primitives, list) else []:
            attributes = primitive.get("attributes", {}) if isinstance(primitive, dict) else {}
            position = attributes.get("POSITION") if isinstance(attributes, dict) else None
            if isinstance(position, int):
                found.add(position)
    return found


def _check_line_budget(data: bytes, max_vertices: int) -> None:
    """A text point cloud holds one point per line: more lines than the cap is too many points,
    and a line longer than a point's row is not one."""
    lines = data.count(b"\n")
    if lines > max_vertices + SPARE_LINES:
        raise TooManyVertices(f"the file holds {lines} lines, more points than the cap of {max_vertices}")
    _require_short_lines(data, MAX_POINT_LINE_BYTES, "point")
