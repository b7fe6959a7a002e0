"""Parse uploaded meshes and point clouds from bytes, safely.

Why this module is careful: an upload is hostile until proven otherwise. The file type
comes from an allow-list, never from sniffing; parsing goes through an in-memory buffer
with an explicit type and a resolver that refuses every external reference, so nothing in a
file (an OBJ ``mtllib``, a glTF buffer URI) can make the server read another file or the
network. Archives are refused outright.
"""

import io
import re
from pathlib import PurePosixPath

import numpy as np
import trimesh
from trimesh.resolvers import Resolver

from app.geometry.declared import check_declared, require_within_caps
from app.geometry.errors import (
    GeometryError,
    InvalidGeometry,
    UnreadableFile,
    UnsupportedFileType,
    library_reason,
)
from app.geometry.formats import ACCEPTED, listed
from app.geometry.shapes import Mesh, PointCloud, Shape

UNIT_TO_METRES = {"m": 1.0, "cm": 0.01, "mm": 0.001}
MAX_POINT_COLUMNS = 16  # x y z, a normal, a colour with alpha, and a few scanner fields

_OBJ_MATERIAL_LINE = re.compile(rb"^[ \t]*(mtllib|usemtl)\b[^\n]*$", re.MULTILINE)


class ExternalReference(UnreadableFile):
    """The file refers to another file or URL, which we never follow."""

    slug = "external-reference"
    title = "External references are not allowed"


class _RefusingResolver(Resolver):
    """A trimesh resolver that refuses every lookup, so loaders cannot reach outside the upload."""

    def __init__(self) -> None:
        pass

    def get(self, key: str) -> bytes:
        raise ExternalReference(f"the file refers to {key!r}; only self-contained files are accepted")

    def write(self, name: str, data: bytes) -> None:
        raise ExternalReference(f"refusing to write {name!r}")

    def namespaced(self, namespace: str) -> "_RefusingResolver":
        return self

    def keys(self) -> list[str]:
        return []


def resolve_file_type(filename: str | None, explicit: str | None = None) -> str:
    """Return the allow-listed file type from an explicit parameter or the upload's extension.

    Raises
    ------
    UnsupportedFileType
        When neither names an allowed type (archives included).
    """
    candidate = explicit or (PurePosixPath(filename).suffix.lstrip(".") if filename else "")
    file_type = candidate.lower().strip()
    if file_type not in ACCEPTED:
        shown = repr(candidate) if candidate else "none"
        raise UnsupportedFileType(f"file type {shown} is not accepted; allowed: {listed()}")
    return file_type


def unit_scale(units: str = "m", scale: float | None = None) -> float:
    """Factor that converts input coordinates to metres; an explicit ``scale`` wins over ``units``."""
    if scale is not None:
        if not np.isfinite(scale) or scale <= 0:
            raise InvalidGeometry(f"scale must be a positive finite number, got {scale}")
        return float(scale)
    if units not in UNIT_TO_METRES:
        raise InvalidGeometry(f"units must be one of {sorted(UNIT_TO_METRES)}, got {units!r}")
    return UNIT_TO_METRES[units]


def load_shape(data: bytes, file_type: str, *, scale: float = 1.0, max_vertices: int) -> Shape:
    """Parse ``data`` as ``file_type`` and return it in metres (coordinates times ``scale``).

    Parameters
    ----------
    data : bytes
        The whole upload.
    file_type : str
        One of :data:`app.geometry.formats.ACCEPTED` (see :func:`resolve_file_type`).
    scale : float
        Multiplier to metres (see :func:`unit_scale`).
    max_vertices : int
        Refuse shapes with more vertices, before allocating them where the format allows.

    Raises
    ------
    UnsupportedFileType, UnreadableFile, TooManyVertices
    """
    if file_type not in ACCEPTED:
        raise UnsupportedFileType(f"file type {file_type!r} is not accepted")
    try:
        shape = _parsed(data, file_type, max_vertices)
    except GeometryError:
        raise
    except Exception as exc:  # a reader's surprise is still the file's problem, never a 500
        cause = _external_reference_in(exc)
        if cause is not None:
            raise cause from exc
        raise UnreadableFile(f"could not parse the {file_type} file: {library_reason(exc)}") from exc
    _require_within_caps(shape, max_vertices)
    return _scaled(shape, scale)


def _parsed(data: bytes, file_type: str, max_vertices: int) -> Shape:
    """The shape the checked bytes hold, in the file's units."""
    if file_type == "npy":
        return _load_npy(data)
    data = check_declared(data, file_type, max_vertices)
    if file_type in ("xyz", "txt"):
        return _load_text_points(data)
    if file_type == "obj":
        # Material libraries only colour the mesh; drop them so they are never looked up.
        data = _OBJ_MATERIAL_LINE.sub(b"", data)
    return _load_with_trimesh(data, file_type, max_vertices)


def _require_within_caps(shape: Shape, max_vertices: int) -> None:
    vertices = len(shape.vertices) if isinstance(shape, Mesh) else len(shape.points)
    faces = len(shape.faces) if isinstance(shape, Mesh) else 0
    require_within_caps(vertices, faces, max_vertices, "the shape holds")


def _scaled(shape: Shape, scale: float) -> Shape:
    if isinstance(shape, Mesh):
        return Mesh(shape.vertices * scale, shape.faces)
    return PointCloud(shape.points * scale, shape.boundary)


def _load_npy(data: bytes) -> PointCloud:
    try:
        points = np.load(io.BytesIO(data), allow_pickle=False)
    except Exception as exc:  # numpy raises several unrelated types for bad bytes
        raise UnreadableFile(f"not a valid .npy file: {library_reason(exc)}") from exc
    if not isinstance(points, np.ndarray):  # np.load opens an .npz archive as a lazy mapping
        points.close()
        raise UnreadableFile("this is an .npz archive, not an .npy array: send the (n, 3) array itself")
    real = np.issubdtype(points.dtype, np.integer) or np.issubdtype(points.dtype, np.floating)
    if points.ndim != 2 or points.shape[1] != 3 or not real:
        raise UnreadableFile(
            f"a .npy point cloud must be a real-valued (n, 3) array, got {points.dtype} {points.shape}"
        )
    return PointCloud(np.asarray(points, dtype=np.float64))


def _load_with_trimesh(data: bytes, file_type: str, max_vertices: int) -> Shape:
    scene = trimesh.load_scene(io.BytesIO(data), file_type=file_type, resolver=_RefusingResolver(), process=False)
    geometries = list(scene.geometry.values())
    if not geometries:
        raise UnreadableFile(f"no geometry found in the {file_type} file")
    if all(isinstance(g, trimesh.PointCloud) for g in geometries):
        return _point_cloud_from(geometries)
    _require_instances_within_caps(scene, max_vertices)
    mesh = _flattened(scene)
    faces, vertices = np.asarray(mesh.faces, dtype=np.int64), np.asarray(mesh.vertices, dtype=np.float64)
    if vertices.ndim != 2 or vertices.shape[1] != 3 or (faces.size and (faces.ndim != 2 or faces.shape[1] != 3)):
        # An OBJ line "v 0" leaves trimesh a (n, 1) or flat vertex array: no shape to read.
        raise UnreadableFile(
            f"the {file_type} file's vertices are not (x, y, z) triples or its faces not triangles "
            f"(vertices {vertices.shape}, faces {faces.shape})"
        )
    faces = faces.reshape(-1, 3)
    if len(faces) == 0:
        return PointCloud(vertices)
    return Mesh(vertices, faces)


def _load_text_points(data: bytes) -> PointCloud:
    """An XYZ / TXT point cloud: one point a row, x y z first, every row as many columns as the
    first, separated by whitespace or, when the first row has a comma, by commas; ``#`` starts a
    comment and a first row of column names is skipped. A row that does not fit is refused
    (decimal commas, a column more or less) rather than regrouped into other points."""
    rows = [line for line in data.splitlines() if line.strip() and not line.lstrip().startswith(b"#")]
    if not rows:
        raise UnreadableFile("the point file holds no rows")
    comma = b"," in rows[0]
    first = rows[0].split(b"," if comma else None)
    if len(first) > MAX_POINT_COLUMNS:  # every row must be as wide: refused before millions of tokens are read
        raise UnreadableFile(f"a point row holds {len(first)} columns; x y z and at most {MAX_POINT_COLUMNS - 3} more")
    points_rows = rows[1:] if not _is_number(first[0]) else rows  # a first row of column names is skipped
    if not points_rows:
        raise UnreadableFile("the point file holds column names and no point rows")
    try:
        points = np.loadtxt(
            io.BytesIO(b"\n".join(points_rows)),
            delimiter="," if comma else None,
            comments="#",
            ndmin=2,
            dtype=np.float64,
        )
    except ValueError as exc:
        reason = library_reason(exc).split("; use")[0]  # numpy's advice is for its own callers
        hint = " (decimal commas? write 0.5, not 0,5)" if comma else ""
        raise UnreadableFile(f"the point rows do not read as x y z rows: {reason}{hint}") from None
    if points.shape[1] < 3:
        raise UnreadableFile(f"a point row needs x, y and z; these rows hold {points.shape[1]} columns")
    return PointCloud(np.ascontiguousarray(points[:, :3]))


def _is_number(token: bytes) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def _flattened(scene: trimesh.Scene) -> trimesh.Trimesh:
    """The scene as one mesh. A scene of one mesh placed as it is (every PLY, STL, OFF and most
    OBJ uploads) is that mesh: ``to_mesh`` would copy, transform by the identity and concatenate
    it, most of the time a body-sized PLY takes to load."""
    nodes = scene.graph.nodes_geometry
    if len(nodes) == 1:
        transform, name = scene.graph[nodes[0]]
        geometry = scene.geometry.get(name)
        if isinstance(geometry, trimesh.Trimesh) and np.array_equal(transform, np.eye(4)):
            return geometry
    return scene.to_mesh()


def _require_instances_within_caps(scene: trimesh.Scene, max_vertices: int) -> None:
    """Count what flattening the scene would make before making it: a small GLB whose tens of
    thousands of nodes instance one mesh expands to millions of vertices, up to the memory cap."""
    vertices = faces = 0
    for name, nodes in scene.graph.geometry_nodes.items():
        geometry = scene.geometry.get(name)
        vertices += len(nodes) * len(getattr(geometry, "vertices", ()))
        faces += len(nodes) * len(getattr(geometry, "faces", ()))
    require_within_caps(vertices, faces, max_vertices, "the scene's instances hold")


def _external_reference_in(exc: BaseException) -> ExternalReference | None:
    """Find our resolver's refusal when a loader wrapped it in its own exception."""
    seen: BaseException | None = exc
    while seen is not None:
        if isinstance(seen, ExternalReference):
            return seen
        seen = seen.__cause__ or seen.__context__
    return None


def _point_cloud_from(geometries: list) -> PointCloud:
    points = np.concatenate([np.asarray(g.vertices, dtype=np.float64) for g in geometries])
    flags = [_ply_boundary_flags(g) for g in geometries]
    boundary = None if any(f is None for f in flags) else np.concatenate(flags)
    return PointCloud(points, boundary)


def _ply_boundary_flags(cloud: trimesh.PointCloud) -> np.ndarray | None:
    """The optional PLY vertex property ``boundary`` (non-zero = boundary point): trimesh keeps an
    ASCII file's properties as a dict of columns and a binary file's as one structured array."""
    raw = cloud.metadata.get("_ply_raw", {}).get("vertex", {}).get("data", {})
    if isinstance(raw, np.ndarray) and raw.dtype.names and "boundary" in raw.dtype.names:
        return np.asarray(raw["boundary"]).reshape(-1) != 0
    if not isinstance(raw, dict) or "boundary" not in raw:
        return None
    return np.asarray(raw["boundary"]).reshape(-1) != 0
