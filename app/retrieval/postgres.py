"""The ShapeDNA store on PostgreSQL, for replicas that share one database.

The retrieval features (log λ₂…λ_k, :mod:`app.retrieval.distance`) are stored as a ``cube``
(contrib extension; pgvector is not packaged here) with a GiST index, so ``ORDER BY features
<-> query LIMIT n`` is an indexed k-NN whose distance is exactly the one SQLite ranks by in
numpy. Schema and extension are created on start-up when absent. One connection per
operation keeps the store safe to share between threads.
"""

import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime

import numpy as np
import psycopg

from app.retrieval.distance import features
from app.retrieval.store import Match, ShapeRecord, StoreUnavailable

SCHEMA = (
    "CREATE EXTENSION IF NOT EXISTS cube",
    """CREATE TABLE IF NOT EXISTS shapes (
        id TEXT PRIMARY KEY,
        label TEXT NOT NULL,
        source TEXT NOT NULL,
        spectrum DOUBLE PRECISION[] NOT NULL,
        features CUBE NOT NULL,
        created_at TEXT NOT NULL
    )""",
    "CREATE INDEX IF NOT EXISTS shapes_features ON shapes USING gist (features)",
)
COLUMNS = "id, label, source, spectrum, created_at"
CONNECT_TIMEOUT_SECONDS = 5


class PostgresStore:
    """Shapes in a PostgreSQL database given by a ``postgresql://`` URL."""

    backend = "postgresql"

    def __init__(self, url: str) -> None:
        self.url = url
        with self._connect() as connection:
            connection.execute("SELECT pg_advisory_xact_lock(7436)")  # replicas starting together
            for statement in SCHEMA:
                connection.execute(statement)

    @contextmanager
    def _connect(self) -> Iterator[psycopg.Connection]:
        try:
            with psycopg.connect(self.url, connect_timeout=CONNECT_TIMEOUT_SECONDS) as connection:  # commits on exit
                yield connection
        except psycopg.OperationalError as exc:  # server down, unreachable, restarting
            raise StoreUnavailable(f"PostgreSQL: {exc}".strip()) from exc

    def ping(self) -> None:
        with self._connect() as connection:
            connection.execute("SELECT 1")

    def add(self, label: str, spectrum: np.ndarray, source: str) -> ShapeRecord:
        record = ShapeRecord(
            uuid.uuid4().hex,
            label,
            source,
            [float(x) for x in spectrum],
            datetime.now(UTC).isoformat(timespec="seconds"),
        )
        with self._connect() as connection:
            connection.execute(
                f"INSERT INTO shapes ({COLUMNS}, features) VALUES (%s, %s, %s, %s, %s, cube(%s::float8[]))",
                (record.id, label, source, record.spectrum, record.created_at, _features(spectrum)),
            )
        return record

    def add_many(self, labels: list[str], spectra: np.ndarray, source: str) -> int:
        now = datetime.now(UTC).isoformat(timespec="seconds")
        rows = [
            (uuid.uuid4().hex, label, source, [float(x) for x in s], now, _features(s))
            for label, s in zip(labels, spectra, strict=True)
        ]
        with self._connect() as connection, connection.cursor() as cursor:
            cursor.executemany(
                f"INSERT INTO shapes ({COLUMNS}, features) VALUES (%s, %s, %s, %s, %s, cube(%s::float8[]))", rows
            )
        return len(rows)

    def count(self) -> int:
        with self._connect() as connection:
            return int(connection.execute("SELECT COUNT(*) FROM shapes").fetchone()[0])

    def page(self, offset: int, limit: int) -> list[ShapeRecord]:
        with self._connect() as connection:
            rows = connection.execute(
                f"SELECT {COLUMNS} FROM shapes ORDER BY created_at, id LIMIT %s OFFSET %s", (limit, offset)
            ).fetchall()
        return [ShapeRecord(r[0], r[1], r[2], list(r[3]), r[4]) for r in rows]

    def delete(self, shape_id: str) -> bool:
        with self._connect() as connection:
            return connection.execute("DELETE FROM shapes WHERE id = %s", (shape_id,)).rowcount > 0

    def nearest(self, spectrum: np.ndarray, top: int) -> list[Match]:
        with self._connect() as connection:
            rows = connection.execute(
                f"SELECT {COLUMNS}, features <-> cube(%s::float8[]) AS distance FROM shapes ORDER BY distance LIMIT %s",
                (_features(spectrum), top),
            ).fetchall()
        return [Match(ShapeRecord(r[0], r[1], r[2], list(r[3]), r[4]), float(r[5])) for r in rows]


def _features(spectrum: np.ndarray) -> list[float]:
    return [float(x) for x in features(np.asarray(spectrum, dtype=np.float64))[0]]
