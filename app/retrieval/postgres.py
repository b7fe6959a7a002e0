"""The ShapeDNA store on PostgreSQL, for replicas that share one database.

k-NN is ranked in each replica from an in-memory copy of the stored features
(:mod:`app.retrieval.feature_copy`), exactly as SQLite's: the 19-dimensional ``cube`` GiST index
this store used before pruned poorly at 10⁶ shapes, worst for a share profile. The
copy reads the rows past the last ``seq`` it has, so every insert takes one advisory lock first:
rows then become visible in ``seq`` order, which a reader's snapshot can trust; deletions are
logged by a trigger under the same lock, and the tables' oids tell recreated ones. Schema changes
are made on start-up (the earlier ``features`` column and its index are dropped).

Connections are reused (:class:`IdleConnections`): opening one, even on loopback, costs as much
as a k-NN over 10⁵ shapes. Each operation takes an idle connection or opens one, runs as
one transaction, and gives it back, so threads share the store safely.
"""

import queue
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime

import numpy as np
import psycopg

from app.retrieval.feature_copy import FeatureCopy
from app.retrieval.store import (
    BODIES_QUERY,
    BODIES_TABLE,
    BODY_COLUMNS,
    DeletionLog,
    Match,
    ShapeRecord,
    StoredBodies,
    StoredBody,
    StoreUnavailable,
    matches,
)

SCHEMA_LOCK = 7436  # replicas starting together change the schema one at a time
INSERT_LOCK = 7437  # every insert and deletion, so that rows and deletions become visible in order
SCHEMA = (
    """CREATE TABLE IF NOT EXISTS shapes (
        id TEXT PRIMARY KEY,
        label TEXT NOT NULL,
        source TEXT NOT NULL,
        spectrum DOUBLE PRECISION[] NOT NULL,
        created_at TEXT NOT NULL
    )""",
    "DROP INDEX IF EXISTS shapes_features",
    "ALTER TABLE shapes DROP COLUMN IF EXISTS features",
    "ALTER TABLE shapes ADD COLUMN IF NOT EXISTS seq BIGSERIAL",
    "CREATE UNIQUE INDEX IF NOT EXISTS shapes_seq ON shapes (seq)",
    # Deletions counted for replicas of the version before the log (a rolling upgrade shares one
    # database); this version reads the log below.
    "CREATE TABLE IF NOT EXISTS store_state (id INTEGER PRIMARY KEY CHECK (id = 1), deletions BIGINT NOT NULL)",
    "INSERT INTO store_state (id, deletions) VALUES (1, 0) ON CONFLICT (id) DO NOTHING",
    """CREATE OR REPLACE FUNCTION count_shape_deletion() RETURNS trigger LANGUAGE plpgsql AS $$
        BEGIN UPDATE store_state SET deletions = deletions + 1 WHERE id = 1; RETURN NULL; END $$""",
    """CREATE OR REPLACE TRIGGER shapes_deleted AFTER DELETE ON shapes
        FOR EACH ROW EXECUTE FUNCTION count_shape_deletion()""",
    # Which rows went, in the order their deletions become visible: a position is taken under
    # the inserts' lock, held to the commit, so no later position is seen before an earlier one.
    "CREATE TABLE IF NOT EXISTS deleted_shapes (position BIGSERIAL PRIMARY KEY, key BIGINT NOT NULL)",
    f"""CREATE OR REPLACE FUNCTION log_shape_deletion() RETURNS trigger LANGUAGE plpgsql AS $$
        BEGIN PERFORM pg_advisory_xact_lock({INSERT_LOCK});
        INSERT INTO deleted_shapes (key) VALUES (OLD.seq); RETURN NULL; END $$""",
    """CREATE OR REPLACE TRIGGER shapes_deletion_logged AFTER DELETE ON shapes
        FOR EACH ROW EXECUTE FUNCTION log_shape_deletion()""",
    BODIES_TABLE.format(blob="BYTEA", real="DOUBLE PRECISION"),
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
            connection.execute("SELECT pg_advisory_xact_lock(%s)", (SCHEMA_LOCK,))
            for statement in SCHEMA:
                connection.execute(statement)
        self._copy = FeatureCopy()
        with self._snapshot() as connection:  # read the features now, not in the first query
            self._copy.synced(_PostgresRows(connection))

    @contextmanager
    def _connect(self) -> Iterator[psycopg.Connection]:
        try:
            with self._connections.transaction() as connection:
                yield connection
        except psycopg.OperationalError as exc:  # server down, unreachable, restarting
            raise StoreUnavailable(f"PostgreSQL: {exc}".strip()) from exc

    @contextmanager
    def _snapshot(self) -> Iterator[psycopg.Connection]:
        """A transaction whose statements all see one snapshot (the copy's rows and the records)."""
        with self._connect() as connection:
            connection.execute("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ")
            yield connection

    def close(self) -> None:
        """Close the idle connections (the service's shutdown)."""
        self._connections.close()

    def ping(self) -> None:
        with self._connect() as connection:
            connection.execute("SELECT 1")

    def add(self, label: str, spectrum: np.ndarray, source: str, body: StoredBody | None = None) -> ShapeRecord:
        record = ShapeRecord(
            uuid.uuid4().hex,
            label,
            source,
            [float(x) for x in spectrum],
            datetime.now(UTC).isoformat(timespec="seconds"),
        )
        with self._connect() as connection:
            connection.execute("SELECT pg_advisory_xact_lock(%s)", (INSERT_LOCK,))
            connection.execute(
                f"INSERT INTO shapes ({COLUMNS}) VALUES (%s, %s, %s, %s, %s)",
                (record.id, label, source, record.spectrum, record.created_at),
            )
            if body is not None:
                row = (record.id, label, _bytes(body.coefficients), body.spread)
                connection.execute(f"INSERT INTO shape_bodies ({BODY_COLUMNS}) VALUES (%s, %s, %s, %s)", row)
        return record

    def add_many(
        self, labels: list[str], spectra: np.ndarray, source: str, bodies: list[StoredBody] | None = None
    ) -> int:
        now = datetime.now(UTC).isoformat(timespec="seconds")
        rows = [
            (uuid.uuid4().hex, label, source, [float(x) for x in s], now)
            for label, s in zip(labels, spectra, strict=True)
        ]
        with self._connect() as connection, connection.cursor() as cursor:
            cursor.execute("SELECT pg_advisory_xact_lock(%s)", (INSERT_LOCK,))
            cursor.executemany(f"INSERT INTO shapes ({COLUMNS}) VALUES (%s, %s, %s, %s, %s)", rows)
            if bodies is not None:
                stored = [(r[0], r[1], _bytes(b.coefficients), b.spread) for r, b in zip(rows, bodies, strict=True)]
                cursor.executemany(f"INSERT INTO shape_bodies ({BODY_COLUMNS}) VALUES (%s, %s, %s, %s)", stored)
        return len(rows)

    def bodies(self) -> StoredBodies:
        with self._snapshot() as connection:
            rows = connection.execute(BODIES_QUERY).fetchall()
        return StoredBodies.of_rows(rows)

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
            deleted = connection.execute("DELETE FROM shapes WHERE id = %s", (shape_id,)).rowcount > 0
            connection.execute("DELETE FROM shape_bodies WHERE id = %s", (shape_id,))
            if deleted:
                _PostgresRows(connection).prune()  # under the lock the deletion's trigger took
        return deleted

    def nearest(self, spectra: np.ndarray, top: int) -> list[Match]:
        with self._snapshot() as connection:
            ranked = self._copy.nearest(_PostgresRows(connection), spectra, top)
            rows = connection.execute(
                f"SELECT seq, {COLUMNS} FROM shapes WHERE seq = ANY(%s)", (ranked.rows.tolist(),)
            ).fetchall()
        return matches(ranked, {r[0]: ShapeRecord(r[1], r[2], r[3], list(r[4]), r[5]) for r in rows})


class _PostgresRows(DeletionLog):
    """The store's rows as one repeatable-read transaction sees them (:class:`FeatureCopy`'s source)."""

    PLACEHOLDER = "%s"

    def version(self) -> tuple[int, int]:
        """The tables' identities: either made again (a restored backup) is other rows, another log."""
        return self._connection.execute(
            "SELECT 'shapes'::regclass::oid::bigint, 'deleted_shapes'::regclass::oid::bigint"
        ).fetchone()

    def last(self) -> int:
        return int(self._connection.execute("SELECT COALESCE(MAX(seq), 0) FROM shapes").fetchone()[0])

    def spectra_after(self, key: int) -> tuple[np.ndarray, np.ndarray]:
        """Read in PostgreSQL's binary array format (``array_send``) and decoded by numpy at once:
        as Python lists of floats, or decoded row by row, 10⁶ rows took many times longer."""
        query = "SELECT seq, array_send(spectrum) FROM shapes WHERE seq > %s ORDER BY seq"
        rows = self._connection.execute(query, (key,)).fetchall()
        keys = np.array([row[0] for row in rows], dtype=np.int64)
        return keys, _float8_arrays([row[1] for row in rows])


def _float8_arrays(arrays: list[bytes]) -> np.ndarray:
    """(n, k) values of n one-dimensional float8[] of one length k (every stored spectrum has the
    store's k) in PostgreSQL's binary array format: a 20-byte header (number of dimensions, null
    flag, element type, length, lower bound), then each element as a 4-byte length and 8
    big-endian bytes."""
    if not arrays:
        return np.zeros((0, 0))
    (length,) = np.frombuffer(arrays[0], dtype=">i4", count=1, offset=12)
    size = _HEADER_BYTES + int(length) * _FLOAT8_ELEMENT.itemsize
    if any(len(array) != size for array in arrays):
        raise ValueError("stored spectra differ in length")
    raw = np.frombuffer(b"".join(arrays), dtype=np.uint8).reshape(len(arrays), size)
    return np.ascontiguousarray(raw[:, _HEADER_BYTES:]).view(_FLOAT8_ELEMENT)["value"].astype(np.float64)


_HEADER_BYTES = 20
_FLOAT8_ELEMENT = np.dtype([("length", ">i4"), ("value", ">f8")])


def _bytes(values: np.ndarray) -> bytes:
    return np.asarray(values, dtype=np.float64).tobytes()
