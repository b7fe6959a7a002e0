"""Scanning sessions on PostgreSQL, for replicas that share one database: the same tables,
statements and rules as SQLite's (:class:`app.sessions.store.SessionRows`). A view is added under
a row lock on its session (``SELECT … FOR UPDATE``), so views posted at once to two replicas land
one after the other; connections are reused as the shape store reuses them."""

from collections.abc import Iterator
from contextlib import contextmanager

import psycopg

from app.retrieval.postgres import IDLE_CONNECTIONS, SCHEMA_LOCK, IdleConnections
from app.retrieval.store import StoreUnavailable
from app.sessions.store import SessionRows

SCHEMA = (
    """CREATE TABLE IF NOT EXISTS scan_sessions (
        id TEXT PRIMARY KEY,
        registered BOOLEAN NOT NULL,
        units TEXT NOT NULL,
        scale DOUBLE PRECISION,
        created_at DOUBLE PRECISION NOT NULL,
        touched_at DOUBLE PRECISION NOT NULL,
        views INTEGER NOT NULL,
        union_views INTEGER,
        union_version TEXT,
        union_text TEXT
    )""",
    """CREATE TABLE IF NOT EXISTS scan_session_views (
        session_id TEXT NOT NULL REFERENCES scan_sessions (id) ON DELETE CASCADE,
        position INTEGER NOT NULL,
        source TEXT NOT NULL,
        eigenvalues BYTEA NOT NULL,
        geometry BYTEA NOT NULL,
        region TEXT NOT NULL,
        confidence DOUBLE PRECISION NOT NULL,
        area DOUBLE PRECISION NOT NULL,
        warnings TEXT NOT NULL,
        PRIMARY KEY (session_id, position)
    )""",
    """CREATE TABLE IF NOT EXISTS service_keys (
        name TEXT PRIMARY KEY,
        secret BYTEA NOT NULL
    )""",
)


class PostgresSessions(SessionRows):
    """Sessions in the PostgreSQL database given by a ``postgresql://`` URL."""

    PLACEHOLDER = "%s"
    LOCK = " FOR UPDATE"

    def __init__(self, url: str, ttl_seconds: float) -> None:
        self.ttl = ttl_seconds
        self._connections = IdleConnections(url, IDLE_CONNECTIONS)
        with self._transaction() as connection:
            connection.execute("SELECT pg_advisory_xact_lock(%s)", (SCHEMA_LOCK,))
            for statement in SCHEMA:
                connection.execute(statement)

    @contextmanager
    def _transaction(self, write: bool = True) -> Iterator[psycopg.Connection]:
        """One pooled connection, one transaction; a read sees one snapshot (repeatable read)."""
        try:
            with self._connections.transaction() as connection:
                if not write:
                    connection.execute("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ")
                yield connection
        except psycopg.OperationalError as exc:  # server down, unreachable, restarting
            raise StoreUnavailable(f"PostgreSQL: {exc}".strip()) from exc

    def close(self) -> None:
        self._connections.close()
