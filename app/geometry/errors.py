"""Input errors raised by the geometry layer: a file that cannot be turned into a spectrum.

Each carries a stable ``slug`` that the API turns into a problem ``type``; the HTTP status
belongs to the API layer, not here.
"""

import re

from app.core.errors import InputError

MAX_REASON_CHARS = 200
_PATH = re.compile(r"(?:[A-Za-z]:)?(?:[/\\][\w.+-]+){2,}(?::\d+)?")


def library_reason(exc: BaseException) -> str:
    """What a library said was wrong with the input, fit for a client: its first line, without
    the file paths and line numbers of where the library was built, and short."""
    first = (str(exc).strip().splitlines() or [type(exc).__name__])[0]
    plain = _PATH.sub("…", first)
    return plain if len(plain) <= MAX_REASON_CHARS else plain[: MAX_REASON_CHARS - 1] + "…"


class GeometryError(InputError):
    """Base class: the input cannot be turned into a spectrum, and the reason is the caller's."""

    slug = "invalid-geometry"
    title = "Invalid geometry"


class UnsupportedFileType(GeometryError):
    """The file type is not on the allow-list (archives, unknown extensions)."""

    slug = "unsupported-file-type"
    title = "Unsupported file type"


class UnreadableFile(GeometryError):
    """The bytes do not parse as the declared file type."""

    slug = "unreadable-file"
    title = "File could not be parsed"


class InvalidGeometry(GeometryError):
    """The file parsed but the shape fails validation (NaNs, bad indices, zero area, too small)."""


class TooManyVertices(GeometryError):
    """The shape exceeds the configured vertex cap."""

    slug = "too-many-vertices"
    title = "Too many vertices"


class TooManyFaces(GeometryError):
    """The shape declares or holds more faces than the cap that goes with the vertex cap."""

    slug = "too-many-faces"
    title = "Too many faces"


class SceneTooLarge(GeometryError):
    """A scene file holds more nodes (instances of its meshes) than a scan ever needs."""

    slug = "scene-too-large"
    title = "Scene too large"


class MissingBoundary(GeometryError):
    """A point cloud was neither declared closed nor given its boundary points."""

    slug = "missing-boundary"
    title = "Point-cloud boundary not given"


class SolverFailure(GeometryError):
    """The eigen-solver did not converge on this input (a pathological shape)."""

    slug = "solver-failure"
    title = "Eigen-solver failed on this shape"
