"""The upload formats the service reads, one record each: the parser's allow-list, the routes'
field descriptions, the session page's file picker, the docs' table and the refusal of any other
type all read this list, so a new format is a record here, its reader in :mod:`app.geometry.io`
and its size check in :mod:`app.geometry.declared`.
"""

from dataclasses import dataclass, field


@dataclass(frozen=True, kw_only=True)
class Format:
    """One accepted file type: its ``name`` (the extension, or the ``file_type`` parameter),
    whether it holds a mesh (a PLY without faces is a point cloud) and points, whether it is text
    (a UTF-8 byte-order mark is dropped before it is read), and how the docs describe it."""

    name: str = field(kw_only=False)
    mesh: bool
    points: bool
    text: bool
    described: str


FORMATS = (
    Format(
        "ply",
        mesh=True,
        points=True,
        text=True,
        described="ASCII or binary; without faces a point cloud, optionally with a vertex property `boundary`",
    ),
    Format("obj", mesh=True, points=False, text=True, described="an `mtllib` or `usemtl` line is ignored"),
    Format("off", mesh=True, points=False, text=True, described="(C/N)OFF headers"),
    Format("stl", mesh=True, points=False, text=True, described="ASCII or binary"),
    Format("glb", mesh=True, points=False, text=False, described="binary glTF; a buffer URI is refused"),
    Format(
        "xyz",
        mesh=False,
        points=True,
        text=True,
        described="one `x y z` or `x,y,z` row a point, every row "
        "as wide as the first; a first row of column names is skipped",
    ),
    Format("txt", mesh=False, points=True, text=True, described="as `xyz`"),
    Format("npy", mesh=False, points=True, text=False, described="an `(n, 3)` real array, no pickles"),
)

ACCEPTED = frozenset(f.name for f in FORMATS)
TEXT_TYPES = frozenset(f.name for f in FORMATS if f.text)


def listed() -> str:
    """The accepted types, comma-separated, in the list's order (for descriptions and refusals)."""
    return ", ".join(f.name for f in FORMATS)


def accept_attribute() -> str:
    """The value of a file input's ``accept`` attribute that offers every accepted type."""
    return ",".join(f".{f.name}" for f in FORMATS)


def markdown_table() -> str:
    """The docs' table of accepted types (``docs/api.md``, between its ``formats`` markers)."""
    rows = ["| type | mesh | point cloud | notes |", "|---|---|---|---|"]
    for f in FORMATS:
        rows.append(f"| `{f.name}` | {'yes' if f.mesh else '—'} | {'yes' if f.points else '—'} | {f.described} |")
    return "\n".join(rows)
