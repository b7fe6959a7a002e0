"""Scanning sessions in the service's database: SQLite by default (this module), PostgreSQL when
replicas share one (:mod:`app.sessions.postgres`).

A session is a row; each view is a row of its own, numbered in the order the views landed. A view
is added in one write transaction that checks the session is there (not ended, not expired) and
not full, takes the next number and touches the session: two views posted at once both land, one
after the other, and neither overwrites the other. An acknowledged view survives a crash (SQLite
``synchronous=FULL`` in WAL mode, as the shape store). The union answered last is cached with the
number of views and the models' version it was read from, so that reading a session does not
solve it again. Sessions untouched for longer than the time-to-live are gone: read as missing,
and deleted with their views when the next session is made.
"""

import secrets
import sqlite3
import time
import uuid
from collections.abc import Iterator
from contextlib import AbstractContextManager, closing, contextmanager
from pathlib import Path
from typing import Any, Protocol

from app.retrieval.store import Connection, StoreUnavailable
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

SCHEMA = (
    """CREATE TABLE IF NOT EXISTS scan_sessions (
        id TEXT PRIMARY KEY,
        registered INTEGER NOT NULL,
        units TEXT NOT NULL,
        scale REAL,
        created_at REAL NOT NULL,
        touched_at REAL NOT NULL,
        views INTEGER NOT NULL,
        union_views INTEGER,
        union_version TEXT,
        union_text TEXT
    )""",
    """CREATE TABLE IF NOT EXISTS scan_session_views (
        session_id TEXT NOT NULL,
        position INTEGER NOT NULL,
        source TEXT NOT NULL,
        eigenvalues BLOB NOT NULL,
        geometry BLOB NOT NULL,
        region TEXT NOT NULL,
        confidence REAL NOT NULL,
        area REAL NOT NULL,
        warnings TEXT NOT NULL,
        PRIMARY KEY (session_id, position)
    )""",
    """CREATE TABLE IF NOT EXISTS service_keys (
        name TEXT PRIMARY KEY,
        secret BLOB NOT NULL
    )""",
)
KEY_BYTES = 32  # a service key: HMAC-SHA256's own size
META_COLUMNS = "id, registered, units, scale, created_at, touched_at, views"


class SessionStore(Protocol):
    """What the sessions routes need from a store; SQLite's and PostgreSQL's provide it."""

    def create(self, registered: bool, units: str, scale: float | None) -> SessionMeta: ...
    def meta(self, session_id: str) -> SessionMeta:
        """The session, or SessionNotFound."""
        ...

    def add_view(self, session_id: str, view: SessionView, max_views: int) -> SessionMeta:
        """Add a view as the session's next; the session after it. SessionNotFound, SessionFull."""
        ...

    def views(self, session_id: str, template_vertices: int) -> tuple[SessionMeta, list[SessionView]]:
        """The session and its views in the order they landed, read in one snapshot."""
        ...

    def cached_union(self, session_id: str, views: int, version: str) -> SessionUnion | None: ...
    def cache_union(self, session_id: str, views: int, version: str, union: SessionUnion) -> None: ...
    def delete(self, session_id: str) -> bool: ...
    def service_key(self, name: str) -> bytes:
        """The secret the service keeps under ``name`` in its database, made on first use: one
        for every replica that shares the database."""
        ...

    def close(self) -> None: ...


def open_sessions(database: Path, url: str | None, ttl_seconds: float) -> SessionStore:
    """The sessions' store in the service's database: PostgreSQL when ``url`` is given, else the
    SQLite file ``database``."""
    if url:
        from app.sessions.postgres import PostgresSessions

        return PostgresSessions(url, ttl_seconds)
    return SQLiteSessions(database, ttl_seconds)


def new_session_id() -> str:
    """A session's id: unguessable, so that knowing one session's id says nothing of another's."""
    return uuid.uuid4().hex


class SessionRows:
    """The sessions' operations, written once for both engines: each runs in one transaction of
    the engine's (``_transaction``), its SQL written with ``?`` marks and the engine's own put in
    (``PLACEHOLDER``); the read of a session a view is added to takes the engine's row lock
    (``LOCK``) where the transaction alone does not keep other writers out."""

    PLACEHOLDER = "?"
    LOCK = ""
    ttl: float

    def _transaction(self, write: bool = True) -> AbstractContextManager[Connection]:
        raise NotImplementedError

    def _run(self, connection: Connection, query: str, parameters: tuple = ()) -> Any:
        return connection.execute(query.replace("?", self.PLACEHOLDER), parameters)

    def _live(self, connection: Connection, session_id: str, lock: bool = False) -> SessionMeta:
        query = f"SELECT {META_COLUMNS} FROM scan_sessions WHERE id = ? AND touched_at >= ?" + (self.LOCK * lock)
        row = self._run(connection, query, (session_id, time.time() - self.ttl)).fetchone()
        if row is None:
            raise SessionNotFound(session_id)
        return _meta(row)

    def create(self, registered: bool, units: str, scale: float | None) -> SessionMeta:
        now = time.time()
        meta = SessionMeta(new_session_id(), registered, units, scale, now, now, 0)
        with self._transaction() as connection:
            expired = "SELECT id FROM scan_sessions WHERE touched_at < ?"
            self._run(connection, f"DELETE FROM scan_session_views WHERE session_id IN ({expired})", (now - self.ttl,))
            self._run(connection, "DELETE FROM scan_sessions WHERE touched_at < ?", (now - self.ttl,))
            self._run(
                connection,
                f"INSERT INTO scan_sessions ({META_COLUMNS}) VALUES (?, ?, ?, ?, ?, ?, ?)",
                (meta.id, registered, units, scale, now, now, 0),
            )
        return meta

    def meta(self, session_id: str) -> SessionMeta:
        with self._transaction(write=False) as connection:
            return self._live(connection, session_id)

    def add_view(self, session_id: str, view: SessionView, max_views: int) -> SessionMeta:
        with self._transaction() as connection:
            meta = self._live(connection, session_id, lock=True)
            if meta.views >= max_views:
                raise SessionFull.holding(meta.views)
            marks = ", ".join("?" * (len(VIEW_COLUMNS) + 2))
            self._run(
                connection,
                f"INSERT INTO scan_session_views (session_id, position, {', '.join(VIEW_COLUMNS)}) VALUES ({marks})",
                (session_id, meta.views, *view_row(view)),
            )
            now = time.time()
            self._run(
                connection, "UPDATE scan_sessions SET views = views + 1, touched_at = ? WHERE id = ?", (now, session_id)
            )
        return SessionMeta(meta.id, meta.registered, meta.units, meta.scale, meta.created_at, now, meta.views + 1)

    def views(self, session_id: str, template_vertices: int) -> tuple[SessionMeta, list[SessionView]]:
        with self._transaction(write=False) as connection:
            meta = self._live(connection, session_id)
            rows = self._run(
                connection,
                f"SELECT {', '.join(VIEW_COLUMNS)} FROM scan_session_views WHERE session_id = ? ORDER BY position",
                (session_id,),
            ).fetchall()
        return meta, [view_of_row(row, template_vertices) for row in rows]

    def cached_union(self, session_id: str, views: int, version: str) -> SessionUnion | None:
        with self._transaction(write=False) as connection:
            row = self._run(
                connection,
                "SELECT union_text FROM scan_sessions WHERE id = ? AND union_views = ? AND union_version = ?",
                (session_id, views, version),
            ).fetchone()
        return union_of_text(row[0]) if row else None

    def cache_union(self, session_id: str, views: int, version: str, union: SessionUnion) -> None:
        """Cache a union read from ``views`` views, unless the session has others by now."""
        with self._transaction() as connection:
            self._run(
                connection,
                "UPDATE scan_sessions SET union_views = ?, union_version = ?, union_text = ? "
                "WHERE id = ? AND views = ?",
                (views, version, union_text(union), session_id, views),
            )

    def delete(self, session_id: str) -> bool:
        with self._transaction() as connection:
            self._run(connection, "DELETE FROM scan_session_views WHERE session_id = ?", (session_id,))
            return self._run(connection, "DELETE FROM scan_sessions WHERE id = ?", (session_id,)).rowcount > 0

    def service_key(self, name: str) -> bytes:
        with self._transaction() as connection:
            self._run(
                connection,
                "INSERT INTO service_keys (name, secret) VALUES (?, ?) ON CONFLICT (name) DO NOTHING",
                (name, secrets.token_bytes(KEY_BYTES)),
            )
            return bytes(self._run(connection, "SELECT secret FROM service_keys WHERE name = ?", (name,)).fetchone()[0])


class SQLiteSessions(SessionRows):
    """Sessions in the service's SQLite file, beside the shape store's tables: every write takes
    the file's write lock first (``BEGIN IMMEDIATE``), so no row lock is needed."""

    def __init__(self, path: Path, ttl_seconds: float) -> None:
        self.path = path
        self.ttl = ttl_seconds
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
        except OSError as exc:
            raise StoreUnavailable(f"cannot create {path.parent}: {exc}") from exc
        try:  # outside a transaction: SQLite changes the journal of a file only there
            with closing(sqlite3.connect(path, timeout=30, isolation_level=None)) as connection:
                connection.execute("PRAGMA journal_mode=WAL")
        except sqlite3.OperationalError as exc:
            raise StoreUnavailable(f"SQLite file {path}: {exc}") from exc
        with self._transaction() as connection:
            for statement in SCHEMA:
                connection.execute(statement)

    @contextmanager
    def _transaction(self, write: bool = True) -> Iterator[sqlite3.Connection]:
        """One short-lived connection, one transaction: ``BEGIN IMMEDIATE`` for a write, so that
        a view's read of the session and its insert are one step no other writer comes between."""
        try:
            connection = sqlite3.connect(self.path, timeout=30, isolation_level=None)
        except sqlite3.OperationalError as exc:
            raise StoreUnavailable(f"SQLite file {self.path}: {exc}") from exc
        try:
            connection.execute("PRAGMA synchronous=FULL")
            connection.execute("BEGIN IMMEDIATE" if write else "BEGIN")
            try:
                yield connection
            except BaseException:
                connection.execute("ROLLBACK")
                raise
            connection.execute("COMMIT")
        except sqlite3.OperationalError as exc:  # locked past the timeout, disk full, file gone
            raise StoreUnavailable(f"SQLite file {self.path}: {exc}") from exc
        finally:
            connection.close()

    def close(self) -> None:
        """Nothing held open: every operation has its own short-lived connection."""


def _meta(row: tuple) -> SessionMeta:
    session_id, registered, units, scale, created_at, touched_at, views = row
    return SessionMeta(session_id, bool(registered), units, scale, float(created_at), float(touched_at), int(views))
