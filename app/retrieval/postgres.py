"""The ShapeDNA store on PostgreSQL, for replicas that share one database.

The retrieval features (log λ₂…λ_k, :mod:`app.retrieval.distance`) are stored as a ``cube``
(contrib extension; pgvector is not packaged here) with a GiST index, so ``ORDER BY features
<-> query LIMIT n`` is an indexed k-NN whose distance is exactly the one SQLite ranks by in
numpy. Schema and extension are created on start-up when absent.

Connections are reused (:class:`IdleConnections`): opening one costs ~10 ms on loopback, as
much as a k-NN over 10⁵ shapes. Each operation takes an idle connection or opens one, runs as
one transaction, and gives it back, so threads share the store safely.
"""

import queue
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
IDLE_CONNECTIONS = 8  # kept open for reuse; more run at once when asked, and are closed after


class IdleConnections:
    """Open connections kept for reuse, checked before each use.

    Not psycopg_pool: its pool waits its whole timeout for a connection when the server is down,
    where a store must answer 503 at once (a refused connection fails in microseconds). Here
    a connection is taken (the most recently used first) or opened, checked by one round trip
    (a server restart leaves dead connections behind, found here before any work is sent on
    them), and given back after a clean transaction; one that failed is closed.
    """

    def __init__(self, url: str, keep: int) -> None:
        self.url = url
        self._idle: queue.LifoQueue[psycopg.Connection] = queue.LifoQueue(maxsize=keep)

    def _take(self) -> psycopg.Connection:
        while True:
            try:
                connection = self._idle.get_nowait()
            except queue.Empty:
                return psycopg.connect(self.url, connect_timeout=CONNECT_TIMEOUT_SECONDS, autocommit=True)
            try:
                connection.execute("SELECT 1")
                return connection
            except psycopg.Error:
                connection.close()

    @contextmanager
    def transaction(self) -> Iterator[psycopg.Connection]:
        """One connection for one transaction: committed on success, rolled back on error."""
        connection = self._take()
        try:
            with connection.transaction():
                yield connection
        except BaseException:
            connection.close()
            raise
        try:
            self._idle.put_nowait(connection)
        except queue.Full:
            connection.close()

    def close(self) -> None:
        while True:
            try:
                self._idle.get_nowait().close()
            except queue.Empty:
                return


class PostgresStore:
    """Shapes in a PostgreSQL database given by a ``postgresql://`` URL."""

    backend = "postgresql"

    def __init__(self, url: str) -> None:
        self.url = url
        self._connections = IdleConnections(url, IDLE_CONNECTIONS)
        with self._connect() as connection:
            connection.execute("SELECT pg_advisory_xact_lock(7436)")  # replicas starting together
            for statement in SCHEMA:
                connection.execute(statement)

    @contextmanager
    def _connect(self) -> Iterator[psycopg.Connection]:
        try:
            with self._connections.transaction() as connection:
                yield connection
        except psycopg.OperationalError as exc:  # server down, unreachable, restarting
            raise StoreUnavailable(f"PostgreSQL: {exc}".strip()) from exc

    def close(self) -> None:
        """Close the idle connections (the service's shutdown)."""
        self._connections.close()

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

    def nearest(self, spectra: np.ndarray, top: int) -> list[Match]:
        """One k-NN through the GiST index per spectrum, merged: a shape among the ``top`` nearest
        to any of them is among the ``top`` nearest to the one it is nearest to, so the merge of
        each spectrum's ``top`` is exact."""
        best: dict[str, Match] = {}
        with self._connect() as connection:
            for query, spectrum in enumerate(np.atleast_2d(np.asarray(spectra, dtype=np.float64))):
                rows = connection.execute(
                    f"SELECT {COLUMNS}, features <-> cube(%s::float8[]) AS distance FROM shapes "
                    "ORDER BY distance LIMIT %s",
                    (_features(spectrum), top),
                ).fetchall()
                for r in rows:
                    if r[0] not in best or float(r[5]) < best[r[0]].distance:
                        best[r[0]] = Match(ShapeRecord(r[0], r[1], r[2], list(r[3]), r[4]), float(r[5]), query)
        return sorted(best.values(), key=lambda match: match.distance)[:top]


def _features(spectrum: np.ndarray) -> list[float]:
    return [float(x) for x in features(np.asarray(spectrum, dtype=np.float64))[0]]
