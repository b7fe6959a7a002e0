"""The ShapeDNA store: complete shapes (id, identity label, spectrum), queried by nearest spectrum.

SQLite is the embedded default: WAL so readers never block the writer, ``synchronous=FULL`` so
an acknowledged write survives a crash, one short-lived connection per operation so threads
and processes share the file safely. k-NN is exact, in numpy, over an in-memory copy of the
stored features (:mod:`app.retrieval.feature_copy`), which reads from the file only the rows
added and the deletions logged since the last query.
"""

import sqlite3
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import UTC, datetime
from pathlib import Path
from typing import Any, Protocol

import numpy as np

from app.retrieval.distance import Ranked
from app.retrieval.feature_copy import DELETIONS_KEPT, FeatureCopy

# A stored shape's body: its shape coefficients in the served body basis (:mod:`app.inference.
# bodyfit`), what identity ranks people by; a shape stored without one is ranked by spectrum only.
BODIES_TABLE = """CREATE TABLE IF NOT EXISTS shape_bodies (
        id TEXT PRIMARY KEY,
        label TEXT NOT NULL,
        coefficients {blob} NOT NULL,
        spread {real} NOT NULL
    )"""
BODY_COLUMNS = "id, label, coefficients, spread"
BODIES_QUERY = (  # a body whose shape is gone is not read, whatever deleted the shape
    "SELECT b.id, b.label, b.coefficients, b.spread FROM shape_bodies b JOIN shapes s ON s.id = b.id ORDER BY b.id"
)
SCHEMA = (
    """CREATE TABLE IF NOT EXISTS shapes (
        id TEXT PRIMARY KEY,
        label TEXT NOT NULL,
        source TEXT NOT NULL,
        spectrum BLOB NOT NULL,
        created_at TEXT NOT NULL
    )""",
    # What an in-memory copy of the features needs to know it is the file's: which file this is
    # (a random name given when the table is made: a restored backup is another file) and which
    # rows were deleted, logged in the file by whichever process deleted them (``deletions``
    # counts them too, as processes of the version before the log read it).
    """CREATE TABLE IF NOT EXISTS store_state (
        id INTEGER PRIMARY KEY CHECK (id = 1),
        file TEXT NOT NULL,
        deletions INTEGER NOT NULL
    )""",
    "INSERT OR IGNORE INTO store_state (id, file, deletions) VALUES (1, lower(hex(randomblob(16))), 0)",
    """CREATE TRIGGER IF NOT EXISTS shapes_deleted AFTER DELETE ON shapes
        BEGIN UPDATE store_state SET deletions = deletions + 1 WHERE id = 1; END""",
    "CREATE TABLE IF NOT EXISTS deleted_shapes (position INTEGER PRIMARY KEY, key INTEGER NOT NULL)",
    """CREATE TRIGGER IF NOT EXISTS shapes_deletion_logged AFTER DELETE ON shapes
        BEGIN INSERT INTO deleted_shapes (key) VALUES (OLD.rowid); END""",
    BODIES_TABLE.format(blob="BLOB", real="REAL"),
)
COLUMNS = "id, label, source, spectrum, created_at"


class StoreUnavailable(Exception):
    """The database cannot be reached or opened: the request is retryable (503), not wrong."""


@dataclass(frozen=True)
class ShapeRecord:
    id: str
    label: str
    source: str
    spectrum: list[float]
    created_at: str


@dataclass(frozen=True)
class StoredBody:
    """A stored shape's body: its person's shape ``coefficients`` (C,) at rest, and their
    ``spread`` (whitened units): how far they may be from the person's own (read at rest: ~0;
    fitted to a posed scan: pose leaks into shape)."""

    coefficients: np.ndarray
    spread: float


@dataclass(frozen=True)
class StoredBodies:
    """The stored shapes that have a body: their ids, labels, coefficients (n, C) and spreads (n,)."""

    ids: list[str]
    labels: list[str]
    coefficients: np.ndarray
    spread: np.ndarray

    @classmethod
    def of_rows(cls, rows: list[tuple]) -> "StoredBodies":
        """From (id, label, coefficients as float64 bytes, spread) rows."""
        if not rows:
            return cls([], [], np.zeros((0, 0)), np.zeros(0))
        ids, labels, blobs, spreads = zip(*rows, strict=True)
        coefficients = np.stack([np.frombuffer(bytes(blob), dtype=np.float64) for blob in blobs])
        return cls(list(ids), list(labels), coefficients, np.asarray(spreads, dtype=np.float64))


@dataclass(frozen=True)
class Match:
    record: ShapeRecord
    distance: float
    query: int = 0  # which of the spectra asked for (``nearest``) the shape is nearest to


class ShapeStore(Protocol):
    """What the API needs from a store; :class:`SQLiteStore` and ``PostgresStore`` provide it."""

    backend: str

    def add(self, label: str, spectrum: np.ndarray, source: str, body: StoredBody | None = None) -> ShapeRecord: ...
    def add_many(
        self, labels: list[str], spectra: np.ndarray, source: str, bodies: list[StoredBody] | None = None
    ) -> int: ...
    def bodies(self) -> StoredBodies:
        """Every stored shape's body (the shapes stored with one)."""
        ...

    def count(self) -> int: ...
    def page(self, offset: int, limit: int) -> list[ShapeRecord]: ...
    def delete(self, shape_id: str) -> bool: ...
    def nearest(self, spectra: np.ndarray, top: int) -> list[Match]:
        """The ``top`` stored shapes nearest to a (k,) spectrum, or to any of (m, k) spectra:
        each shape at its distance to the nearest of them (Match.query says which)."""
        ...

    def ping(self) -> None: ...
    def close(self) -> None: ...


class SQLiteStore:
    """Shapes in one SQLite file."""

    backend = "sqlite"

    def __init__(self, path: Path) -> None:
        self.path = path
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreUnavailable(f"cannot create {path.parent}: {exc}") from exc
        self._copy = FeatureCopy()
        with self._connect() as connection:
            connection.execute("PRAGMA journal_mode=WAL")
            for statement in SCHEMA:
                connection.execute(statement)
        with self._connect() as connection:  # read the features now, not in the first query
            self._copy.synced(_SQLiteRows(connection))

    @contextmanager
    def _connect(self) -> Iterator[sqlite3.Connection]:
        try:
            connection = sqlite3.connect(self.path, timeout=30)
        except sqlite3.OperationalError as exc:
            raise StoreUnavailable(f"SQLite file {self.path}: {exc}") from exc
        try:
            connection.execute("PRAGMA synchronous=FULL")
            with connection:  # commits on success, rolls back on error
                yield connection
        except sqlite3.OperationalError as exc:  # locked past the timeout, disk full, file gone
            raise StoreUnavailable(f"SQLite file {self.path}: {exc}") from exc
        finally:
            connection.close()

    def ping(self) -> None:
        with self._connect() as connection:
            connection.execute("SELECT 1 FROM shapes LIMIT 1")

    def close(self) -> None:
        """Nothing held open: every operation has its own short-lived connection."""

    def add(self, label: str, spectrum: np.ndarray, source: str, body: StoredBody | None = None) -> ShapeRecord:
        record = ShapeRecord(
            id=uuid.uuid4().hex,
            label=label,
            source=source,
            spectrum=[float(x) for x in spectrum],
            created_at=datetime.now(UTC).isoformat(timespec="seconds"),
        )
        with self._connect() as connection:
            connection.execute(
                "INSERT INTO shapes (id, label, source, spectrum, created_at) VALUES (?, ?, ?, ?, ?)",
                (record.id, label, source, _blob(spectrum), record.created_at),
            )
            if body is not None:
                row = (record.id, label, _blob(body.coefficients), body.spread)
                connection.execute(f"INSERT INTO shape_bodies ({BODY_COLUMNS}) VALUES (?, ?, ?, ?)", row)
        return record

    def add_many(
        self, labels: list[str], spectra: np.ndarray, source: str, bodies: list[StoredBody] | None = None
    ) -> int:
        """Insert a batch in one transaction (the seed database)."""
        now = datetime.now(UTC).isoformat(timespec="seconds")
        rows = [(uuid.uuid4().hex, label, source, _blob(s), now) for label, s in zip(labels, spectra, strict=True)]
        with self._connect() as connection:
            connection.executemany(
                "INSERT INTO shapes (id, label, source, spectrum, created_at) VALUES (?, ?, ?, ?, ?)", rows
            )
            if bodies is not None:
                stored = [(r[0], r[1], _blob(b.coefficients), b.spread) for r, b in zip(rows, bodies, strict=True)]
                connection.executemany(f"INSERT INTO shape_bodies ({BODY_COLUMNS}) VALUES (?, ?, ?, ?)", stored)
        return len(rows)

    def bodies(self) -> StoredBodies:
        with self._connect() as connection:
            rows = connection.execute(BODIES_QUERY).fetchall()
        return StoredBodies.of_rows(rows)

    def count(self) -> int:
        with self._connect() as connection:
            return int(connection.execute("SELECT COUNT(*) FROM shapes").fetchone()[0])

    def page(self, offset: int, limit: int) -> list[ShapeRecord]:
        with self._connect() as connection:
            rows = connection.execute(
                f"SELECT {COLUMNS} FROM shapes ORDER BY created_at, id LIMIT ? OFFSET ?",
                (limit, offset),
            ).fetchall()
        return [_record(row) for row in rows]

    def delete(self, shape_id: str) -> bool:
        with self._connect() as connection:
            deleted = connection.execute("DELETE FROM shapes WHERE id = ?", (shape_id,)).rowcount > 0
            connection.execute("DELETE FROM shape_bodies WHERE id = ?", (shape_id,))
            if deleted:
                DeletionLog(connection).prune()
        return deleted

    def nearest(self, spectra: np.ndarray, top: int) -> list[Match]:
        with self._connect() as connection:
            connection.execute("BEGIN")  # one snapshot: the copy's rows and the records read back
            ranked = self._copy.nearest(_SQLiteRows(connection), spectra, top)
            chosen = ranked.rows.tolist()
            rows = connection.execute(
                f"SELECT rowid, {COLUMNS} FROM shapes WHERE rowid IN ({','.join('?' * len(chosen))})", chosen
            ).fetchall()
        return matches(ranked, {row[0]: _record(row[1:]) for row in rows})


class Connection(Protocol):
    """What a source reads through: SQLite's and psycopg's connections alike."""

    def execute(self, query: str, parameters: tuple = ..., /) -> Any: ...


class DeletionLog:
    """A store's ``deleted_shapes`` log (both stores keep it, filled by a trigger) through one
    connection: read in one snapshot by the two :class:`FeatureCopy` sources, pruned by the
    stores' deletions to the last :data:`DELETIONS_KEPT`."""

    PLACEHOLDER = "?"  # the driver's parameter marker

    def __init__(self, connection: Connection) -> None:
        self._connection = connection

    def deletions(self) -> int:
        return int(self._connection.execute("SELECT COALESCE(MAX(position), 0) FROM deleted_shapes").fetchone()[0])

    def forgotten(self) -> int:
        """The position through which the log may have been pruned (0: nothing pruned)."""
        return int(self._connection.execute("SELECT COALESCE(MIN(position), 1) - 1 FROM deleted_shapes").fetchone()[0])

    def prune(self) -> None:
        """Forget all but the last :data:`DELETIONS_KEPT` deletions: an index range, nothing at
        all until the log holds more. Run in the deleting transaction, after its deletion."""
        self._connection.execute(
            "DELETE FROM deleted_shapes WHERE position <= "
            f"(SELECT MAX(position) FROM deleted_shapes) - {self.PLACEHOLDER}",
            (DELETIONS_KEPT,),
        )

    def deleted_after(self, position: int) -> tuple[np.ndarray, np.ndarray]:
        query = f"SELECT position, key FROM deleted_shapes WHERE position > {self.PLACEHOLDER}"
        logged = np.array(self._connection.execute(query, (position,)).fetchall(), dtype=np.int64).reshape(-1, 2)
        return logged[:, 0], logged[:, 1]


class _SQLiteRows(DeletionLog):
    """The store's rows as one SQLite transaction sees them (:class:`FeatureCopy`'s source)."""

    def version(self) -> str:
        return self._connection.execute("SELECT file FROM store_state WHERE id = 1").fetchone()[0]

    def last(self) -> int:
        return int(self._connection.execute("SELECT COALESCE(MAX(rowid), 0) FROM shapes").fetchone()[0])

    def spectra_after(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """The blobs decoded at once (every stored spectrum has the store's k): one array per row
        was a third of an open's time at 10⁶ rows."""
        rows = self._connection.execute(
            "SELECT rowid, spectrum FROM shapes WHERE rowid > ? ORDER BY rowid", (key,)
        ).fetchall()
        if not rows:
            return np.zeros(0, dtype=np.int64), np.zeros((0, 0))
        keys, blobs = zip(*rows, strict=True)
        if len({len(blob) for blob in blobs}) != 1:
            raise ValueError("stored spectra differ in length")
        spectra = np.frombuffer(b"".join(blobs), dtype=np.float64).reshape(len(blobs), -1)
        return np.array(keys, dtype=np.int64), spectra


def matches(ranked: Ranked, records: dict[int, ShapeRecord]) -> list[Match]:
    """The ranking (rows given by key) as matches, ``records`` holding the ranked rows' records by key."""
    return [
        Match(records[key], float(distance), int(query))
        for key, distance, query in zip(ranked.rows.tolist(), ranked.distances, ranked.queries, strict=True)
    ]


def _blob(spectrum: np.ndarray) -> bytes:
    return np.asarray(spectrum, dtype=np.float64).tobytes()


def _record(row: tuple) -> ShapeRecord:
    spectrum = np.frombuffer(row[3], dtype=np.float64)
    return ShapeRecord(row[0], row[1], row[2], [float(x) for x in spectrum], row[4])
