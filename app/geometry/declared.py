"""What a text or PLY file declares, checked against what it holds, before a parser expands it.

A parser's cost follows what the file says, not what it honestly contains: an ASCII PLY that
declares three vertices and then carries 15 M lines took trimesh 42 s to read, an OFF with
fewer vertices than its header names was read as a different mesh, and trimesh reads a PLY
face index of 1.5 as 1, an OBJ index 0 (OBJ counts from 1) as the last vertex, and a list
count of −3 as no face at all. Each check here is a scan of the bytes (no parse), so a file
that lies about itself is refused in milliseconds and a file that does not is read as before.
"""

import json
import re
import struct
from dataclasses import dataclass

from app.geometry.errors import SceneTooLarge, TooManyFaces, TooManyVertices, UnreadableFile

# A closed triangle mesh has about two faces per vertex; four leaves room for meshes whose
# vertices are split at seams, and still bounds what a face list can cost.
FACES_PER_VERTEX = 4
MAX_POLYGON_SIDES = 64  # a polygon is fanned into triangles; scanners write triangles and quads
HEADER_BYTES = 65536
MAX_SCENE_NODES = 1000  # a scan is a mesh or a few; trimesh took 0.8 s just to read 30 000 nodes
SPARE_LINES = 64  # blank and comment lines tolerated beyond the declared rows, not 15 M of them

_PLY_FORMAT = re.compile(rb"^format\s+(ascii|binary_little_endian|binary_big_endian)\s", re.MULTILINE)
_PLY_ELEMENT = re.compile(rb"^element\s+(\S+)\s+(\S+)\s*$", re.MULTILINE)
_PLY_END = re.compile(rb"^end_header[ \t]*\r?\n", re.MULTILINE)
_OFF_COUNTS = re.compile(rb"\A\s*(?:#[^\n]*\n\s*)*[CN]?OFF\s+(?:#[^\n]*\n\s*)*(\d+)\s+(\d+)\s+\d+", re.DOTALL)
_OBJ_ZERO_INDEX = re.compile(rb"^[ \t]*f[ \t][^\n]*?(?<=[ \t])-?0+(?=[/ \t\r\n]|$)", re.MULTILINE)
_NOT_INTEGERS = re.compile(rb"[^0-9 \t\r\n-]")


@dataclass(frozen=True)
class PlyHeader:
    """The parts of a PLY header that say how much data follows."""

    ascii: bool
    elements: list[tuple[str, int]]  # in file order
    body_start: int  # offset of the first data byte


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


def check_declared(data: bytes, file_type: str, max_vertices: int) -> None:
    """Refuse a file whose declared or actual size exceeds the caps, or whose body is not what
    its header declares, before it is parsed; see the module docstring."""
    if file_type == "ply":
        _check_ply(data, max_vertices)
    elif file_type == "off":
        _check_off(data, max_vertices)
    elif file_type == "obj":
        if _OBJ_ZERO_INDEX.search(data):
            raise UnreadableFile("an OBJ face uses vertex index 0; OBJ indices start at 1 (or count back from -1)")
    elif file_type == "glb":
        _check_glb(data)
    elif file_type in ("xyz", "txt"):
        _check_line_budget(data, max_vertices)


def parse_ply_header(data: bytes) -> PlyHeader:
    """The format, element counts and data offset of a PLY, or :class:`UnreadableFile`."""
    end = _PLY_END.search(data, 0, HEADER_BYTES)
    if not data.startswith(b"ply") or end is None:
        raise UnreadableFile(f"not a PLY file: no 'ply' magic or no end_header in its first {HEADER_BYTES} bytes")
    header = data[: end.start()]
    fmt = _PLY_FORMAT.search(header)
    if fmt is None:
        raise UnreadableFile("the PLY header has no valid format line")
    elements = []
    for name, count in _PLY_ELEMENT.findall(header):
        if not count.isdigit():
            raise UnreadableFile(f"the PLY element {name.decode(errors='replace')!r} has count {count!r}")
        elements.append((name.decode(errors="replace"), int(count)))
    return PlyHeader(fmt.group(1) == b"ascii", elements, end.end())


def _check_ply(data: bytes, max_vertices: int) -> None:
    header = parse_ply_header(data)
    counts = dict(header.elements)
    require_within_caps(counts.get("vertex", 0), counts.get("face", 0), max_vertices, "the PLY header declares")
    if header.ascii:
        _check_ascii_ply_body(data[header.body_start :], header.elements)


def _check_ascii_ply_body(body: bytes, elements: list[tuple[str, int]]) -> None:
    """One line per declared element, and face rows of whole indices with sane list counts."""
    declared = sum(count for _, count in elements)
    lines = _data_lines(body, declared, "the PLY header declares")
    start = 0
    for name, count in elements:
        if name == "face":
            _check_face_rows(lines[start : start + count])
        start += count


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
        sides = int(tokens[0])
        if not 3 <= sides <= MAX_POLYGON_SIDES or len(tokens) < 1 + sides:
            raise UnreadableFile(
                f"PLY face {index} lists {tokens[0].decode()} vertices with {len(tokens) - 1} indices "
                f"(a face has 3 to {MAX_POLYGON_SIDES})"
            )


def _check_off(data: bytes, max_vertices: int) -> None:
    counts = _OFF_COUNTS.match(data[:HEADER_BYTES])
    if counts is None:
        raise UnreadableFile("not an OFF file: no OFF keyword followed by vertex, face and edge counts")
    vertices, faces = int(counts.group(1)), int(counts.group(2))
    require_within_caps(vertices, faces, max_vertices, "the OFF header declares")
    _data_lines(data[counts.end() :], vertices + faces, "the OFF header declares")


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


def _check_line_budget(data: bytes, max_vertices: int) -> None:
    """A text point cloud holds one point per line: more lines than the cap is too many points."""
    lines = data.count(b"\n")
    if lines > max_vertices + SPARE_LINES:
        raise TooManyVertices(f"the file holds {lines} lines, more points than the cap of {max_vertices}")
