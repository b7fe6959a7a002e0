"""Scanning sessions on PostgreSQL, for replicas that share one database: the same tables and
rules as SQLite's (:mod:`app.sessions.store`). A view is added under a row lock on its session
(``SELECT … FOR UPDATE``), so views posted at once to two replicas land one after the other;
connections are reused as the shape store reuses them."""

import time
from collections.abc import Iterator
from contextlib import contextmanager

import psycopg

from app.retrieval.postgres import IDLE_CONNECTIONS, SCHEMA_LOCK, IdleConnections
from app.retrieval.store import StoreUnavailable
from app.sessions.records import (
    VIEW_COLUMNS,
    SessionFull,
    SessionMeta,
    SessionNotFound,
    union_of_text,
    union_text,
    view_of_row,
    view_row,
)
from app.sessions.session import SessionUnion, SessionView
from app.sessions.store import META_COLUMNS, new_session_id

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
)


class PostgresSessions:
    """Sessions in the PostgreSQL database given by a ``postgresql://`` URL."""

    def __init__(self, url: str, ttl_seconds: float) -> None:
        self.ttl = ttl_seconds
        self._connections = IdleConnections(url, IDLE_CONNECTIONS)
        with self._transaction() as connection:
            connection.execute("SELECT pg_advisory_xact_lock(%s)", (SCHEMA_LOCK,))
            for statement in SCHEMA:
                connection.execute(statement)

    @contextmanager
    def _transaction(self) -> Iterator[psycopg.Connection]:
        try:
            with self._connections.transaction() as connection:
                yield connection
        except psycopg.OperationalError as exc:  # server down, unreachable, restarting
            raise StoreUnavailable(f"PostgreSQL: {exc}".strip()) from exc

    def _live(self, connection: psycopg.Connection, session_id: str, lock: bool = False) -> SessionMeta:
        row = connection.execute(
            f"SELECT {META_COLUMNS} FROM scan_sessions WHERE id = %s AND touched_at >= %s"
            + (" FOR UPDATE" if lock else ""),
            (session_id, time.time() - self.ttl),
        ).fetchone()
        if row is None:
            raise SessionNotFound(session_id)
        return SessionMeta(row[0], bool(row[1]), row[2], row[3], float(row[4]), float(row[5]), int(row[6]))

    def create(self, registered: bool, units: str, scale: float | None) -> SessionMeta:
        now = time.time()
        meta = SessionMeta(new_session_id(), registered, units, scale, now, now, 0)
        with self._transaction() as connection:
            connection.execute("DELETE FROM scan_sessions WHERE touched_at < %s", (now - self.ttl,))
            connection.execute(
                f"INSERT INTO scan_sessions ({META_COLUMNS}) VALUES (%s, %s, %s, %s, %s, %s, %s)",
                (meta.id, registered, units, scale, now, now, 0),
            )
        return meta

    def meta(self, session_id: str) -> SessionMeta:
        with self._transaction() as connection:
            return self._live(connection, session_id)

    def add_view(self, session_id: str, view: SessionView, max_views: int) -> SessionMeta:
        with self._transaction() as connection:
            meta = self._live(connection, session_id, lock=True)
            if meta.views >= max_views:
                raise SessionFull(f"the session holds {meta.views} views, as many as this service keeps")
            marks = ", ".join(["%s"] * (len(VIEW_COLUMNS) + 2))
            connection.execute(
                f"INSERT INTO scan_session_views (session_id, position, {', '.join(VIEW_COLUMNS)}) VALUES ({marks})",
                (session_id, meta.views, *view_row(view)),
            )
            now = time.time()
            connection.execute(
                "UPDATE scan_sessions SET views = views + 1, touched_at = %s WHERE id = %s", (now, session_id)
            )
        return SessionMeta(meta.id, meta.registered, meta.units, meta.scale, meta.created_at, now, meta.views + 1)

    def views(self, session_id: str, template_vertices: int) -> tuple[SessionMeta, list[SessionView]]:
        with self._transaction() as connection:
            connection.execute("SET TRANSACTION ISOLATION LEVEL REPEATABLE READ")
            meta = self._live(connection, session_id)
            rows = connection.execute(
                f"SELECT {', '.join(VIEW_COLUMNS)} FROM scan_session_views WHERE session_id = %s ORDER BY position",
                (session_id,),
            ).fetchall()
        return meta, [view_of_row(row, template_vertices) for row in rows]

    def cached_union(self, session_id: str, views: int, version: str) -> SessionUnion | None:
        with self._transaction() as connection:
            row = connection.execute(
                "SELECT union_text FROM scan_sessions WHERE id = %s AND union_views = %s AND union_version = %s",
                (session_id, views, version),
            ).fetchone()
        return union_of_text(row[0]) if row else None

    def cache_union(self, session_id: str, views: int, version: str, union: SessionUnion) -> None:
        with self._transaction() as connection:
            connection.execute(
                "UPDATE scan_sessions SET union_views = %s, union_version = %s, union_text = %s "
                "WHERE id = %s AND views = %s",
                (views, version, union_text(union), session_id, views),
            )

    def delete(self, session_id: str) -> bool:
        with self._transaction() as connection:
            return connection.execute("DELETE FROM scan_sessions WHERE id = %s", (session_id,)).rowcount > 0

    def close(self) -> None:
        self._connections.close()
