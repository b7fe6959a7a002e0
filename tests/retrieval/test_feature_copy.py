"""Both stores rank from an in-memory copy of their features: every answer must still be the one
reading every stored row gives, whoever wrote the database and however.

Two stores on one database stand for two processes (replicas) of the service, each with its own
copy; the brute-force truth is computed from what the database holds, read directly.
"""

import sqlite3
from concurrent.futures import ThreadPoolExecutor

import numpy as np
import psycopg
import pytest

from app.retrieval import feature_copy, store
from app.retrieval.distance import nearest_of
from app.retrieval.postgres import PostgresStore
from app.retrieval.store import SQLiteStore
from tests.retrieval.test_stores import spectra


class Database:
    """One database as the tests read it: stores on it, and its rows in key order."""

    def __init__(self, kind: str, place) -> None:
        self.kind, self.place = kind, place

    def store(self):
        return SQLiteStore(self.place) if self.kind == "sqlite" else PostgresStore(self.place)

    def rows(self) -> list[tuple[str, str, np.ndarray]]:
        """(id, label, spectrum) of every row, in key order."""
        if self.kind == "sqlite":
            with sqlite3.connect(self.place) as connection:
                found = connection.execute("SELECT id, label, spectrum FROM shapes ORDER BY rowid").fetchall()
            return [(i, label, np.frombuffer(blob, dtype=np.float64)) for i, label, blob in found]
        with psycopg.connect(self.place) as connection:
            found = connection.execute("SELECT id, label, spectrum FROM shapes ORDER BY seq").fetchall()
        return [(i, label, np.array(values)) for i, label, values in found]

    def logged(self) -> int:
        """How many deletions the log holds."""
        connect = sqlite3.connect if self.kind == "sqlite" else psycopg.connect
        with connect(self.place) as connection:
            return int(connection.execute("SELECT COUNT(*) FROM deleted_shapes").fetchone()[0])

    def truth(self, query: np.ndarray, top: int) -> list[str]:
        """The labels of the ``top`` stored shapes nearest ``query``, from every row."""
        rows = self.rows()
        stored = np.stack([spectrum for _, _, spectrum in rows])
        order = np.argsort(nearest_of(query, stored)[0], kind="stable")[:top]
        return [rows[i][1] for i in order]


@pytest.fixture(params=["sqlite", "postgresql"])
def database(request, tmp_path) -> Database:
    if request.param == "sqlite":
        return Database("sqlite", tmp_path / "shapes.sqlite")
    return Database("postgresql", request.getfixturevalue("fresh_postgres"))


def test_every_answer_is_the_database_s_whatever_another_process_wrote(database):
    reader, writer = database.store(), database.store()
    rng = np.random.default_rng(0)
    pool = spectra(400, 5)
    for step in range(60):
        ids = [row[0] for row in database.rows()]
        action = rng.integers(4)
        if action == 0 or not ids:
            many = pool[rng.integers(len(pool), size=int(rng.integers(1, 20)))]
            writer.add_many([f"s{step}-{i}" for i in range(len(many))], many, "test")
        elif action == 1:
            (writer if step % 2 else reader).add(f"s{step}", pool[rng.integers(len(pool))], "test")
        else:  # delete; at times the newest row, whose rowid SQLite may hand to the next insert
            victim = ids[-1] if action == 2 else ids[int(rng.integers(len(ids)))]
            assert (reader if step % 3 else writer).delete(victim)
        query = pool[rng.integers(len(pool))] * rng.uniform(0.97, 1.03)
        assert [m.record.label for m in reader.nearest(query, 7)] == database.truth(query, 7), step


def test_a_file_of_an_earlier_version_is_ranked_and_its_deletions_seen(tmp_path):
    """A SQLite file made before the deletions count existed gets it on opening."""
    path = tmp_path / "old.sqlite"
    stored = spectra(30, 6)
    with sqlite3.connect(path) as connection:
        connection.execute(
            "CREATE TABLE shapes (id TEXT PRIMARY KEY, label TEXT NOT NULL, source TEXT NOT NULL, "
            "spectrum BLOB NOT NULL, created_at TEXT NOT NULL)"
        )
        connection.executemany(
            "INSERT INTO shapes VALUES (?, ?, 'old', ?, '2026-01-01T00:00:00+00:00')",
            [(f"id{i}", f"person-{i}", s.tobytes()) for i, s in enumerate(stored)],
        )
    store = SQLiteStore(path)
    query = stored[4] * 1.01
    assert store.nearest(query, 1)[0].record.label == "person-4"
    assert store.delete("id4")
    assert store.nearest(query, 1)[0].record.label != "person-4"
    assert [m.record.label for m in store.nearest(query, 5)] == Database("sqlite", path).truth(query, 5)


def test_a_database_of_the_gist_version_is_ranked_and_its_deletions_seen(fresh_postgres):
    """A PostgreSQL table made by the version that ranked through a ``cube`` GiST index: opened,
    it loses that column and index, gains the key the copy reads by, and ranks as before."""
    stored = spectra(30, 14)
    with psycopg.connect(fresh_postgres, autocommit=True) as connection:
        connection.execute("CREATE EXTENSION IF NOT EXISTS cube")
        connection.execute(
            "CREATE TABLE shapes (id TEXT PRIMARY KEY, label TEXT NOT NULL, source TEXT NOT NULL, "
            "spectrum DOUBLE PRECISION[] NOT NULL, features CUBE NOT NULL, created_at TEXT NOT NULL)"
        )
        connection.execute("CREATE INDEX shapes_features ON shapes USING gist (features)")
        for i, spectrum in enumerate(stored):
            connection.execute(
                "INSERT INTO shapes VALUES (%s, %s, 'old', %s, cube(%s::float8[]), '2026-01-01T00:00:00+00:00')",
                (f"id{i}", f"person-{i}", spectrum.tolist(), np.log(spectrum[1:]).tolist()),
            )
    store = PostgresStore(fresh_postgres)
    query = stored[4] * 1.01
    assert store.nearest(query, 1)[0].record.label == "person-4"
    assert store.delete("id4")
    database = Database("postgresql", fresh_postgres)
    assert [m.record.label for m in store.nearest(query, 5)] == database.truth(query, 5)
    with psycopg.connect(fresh_postgres) as connection:
        columns = {
            row[0]
            for row in connection.execute(
                "SELECT column_name FROM information_schema.columns WHERE table_name = 'shapes'"
            )
        }
    assert "features" not in columns and "seq" in columns


def test_an_empty_store_answers_nothing_and_then_its_first_shape(database):
    store = database.store()
    assert store.nearest(spectra(1, 7)[0], 3) == []
    record = store.add("first", spectra(1, 8)[0], "test")
    assert [m.record.id for m in store.nearest(spectra(1, 7)[0], 3)] == [record.id]


def test_a_database_replaced_by_a_smaller_one_is_read_again(database, tmp_path):
    """A backup restored under a running service (SQLite: another file at the path; PostgreSQL:
    the table dropped and made again): no deletion was counted, but the rows are others."""
    store = database.store()
    store.add_many([f"old-{i}" for i in range(10)], spectra(10, 9), "test")
    query = spectra(1, 10)[0]
    assert store.nearest(query, 1)[0].record.label.startswith("old-")
    if database.kind == "sqlite":
        for leftover in tmp_path.glob("shapes.sqlite*"):
            leftover.unlink()
    else:
        with psycopg.connect(database.place, autocommit=True) as connection:
            connection.execute("DROP TABLE shapes")
    database.store().add_many([f"new-{i}" for i in range(3)], spectra(3, 11), "test")
    assert [m.record.label for m in store.nearest(query, 3)] == database.truth(query, 3)


def test_threads_ranking_while_another_inserts_and_deletes_all_get_the_database_s_answer(database):
    """The service's k-NN requests share one store from several threads while uploads add shapes
    and others are deleted: rows added far from the queries (three times the scale), and deleted
    again (at times the newest), never change their answer, so every answer, whatever snapshot its
    thread read, must be the one computed before; a worker's exception surfaces through its future."""
    store, writer = database.store(), database.store()
    near = spectra(300, 12)
    store.add_many([f"near-{i}" for i in range(300)], near, "test")
    queries = near[:20] * 1.01
    expected = [database.truth(query, 5) for query in queries]
    far = spectra(150, 13) * 3

    def rank(round_: int) -> list[list[str]]:
        return [[m.record.label for m in store.nearest(query, 5)] for query in queries[round_ % 2 :: 2]]

    with ThreadPoolExecutor(max_workers=4) as pool:
        answers = [pool.submit(rank, i) for i in range(12)]
        added = []
        for i, spectrum in enumerate(far):
            added.append(writer.add(f"far-{i}", spectrum, "test").id)
            if i % 3 == 2:  # the one before, or (every other time) the newest
                assert writer.delete(added.pop(-1 if i % 6 == 5 else -2))
        for i, answer in enumerate(answers):
            assert answer.result(timeout=60) == expected[i % 2 :: 2]
    assert store.count() == 400
    assert [m.record.label for m in store.nearest(far[7] * 1.01, 3)] == database.truth(far[7] * 1.01, 3)


def test_a_deletion_rolled_back_leaves_a_gap_in_the_log_and_nothing_else(fresh_postgres):
    """A deletion that rolls back consumes its log position: the copy must still see the
    deletions after it, and never the one that did not happen."""
    database = Database("postgresql", fresh_postgres)
    store = database.store()
    stored = spectra(40, 15)
    store.add_many([f"person-{i}" for i in range(40)], stored, "test")
    query = stored[8] * 1.01
    assert store.nearest(query, 1)[0].record.label == "person-8"
    ids = {label: i for i, label, _ in database.rows()}
    with psycopg.connect(fresh_postgres) as connection:
        connection.execute("DELETE FROM shapes WHERE id = %s", (ids["person-8"],))
        connection.rollback()
    assert store.nearest(query, 1)[0].record.label == "person-8"
    assert store.delete(ids["person-9"]) and store.delete(ids["person-3"])
    assert [m.record.label for m in store.nearest(query, 6)] == database.truth(query, 6)
    with psycopg.connect(fresh_postgres) as connection:
        positions = [row[0] for row in connection.execute("SELECT position FROM deleted_shapes ORDER BY position")]
    assert positions == [2, 3]  # position 1 went to the deletion rolled back


def test_a_log_pruned_past_another_process_s_last_read_is_not_trusted(database, monkeypatch):
    """Each deletion prunes the log to its last DELETIONS_KEPT: a process that last read the log
    before the oldest kept deletion reads every row again, one that kept up reads the log; every
    answer is the database's."""
    for module in (feature_copy, store):
        monkeypatch.setattr(module, "DELETIONS_KEPT", 3)
    reader, writer = database.store(), database.store()
    stored = spectra(80, 16)
    writer.add_many([f"person-{i}" for i in range(len(stored))], stored, "test")
    query = stored[40] * 1.001
    ids = [row[0] for row in database.rows()]
    near = [ids[int(i)] for i in np.argsort(nearest_of(query, stored)[0]) if int(i) != len(ids) - 1][:12]
    assert [m.record.label for m in reader.nearest(query, 7)] == database.truth(query, 7)
    for victim in near[:2]:  # fewer than the log keeps
        assert writer.delete(victim)
    assert [m.record.label for m in reader.nearest(query, 7)] == database.truth(query, 7)
    for victim in near[2:10]:  # more than the log keeps, the reader idle
        assert writer.delete(victim)
    assert database.logged() == 3
    assert [m.record.label for m in reader.nearest(query, 7)] == database.truth(query, 7)
    assert not writer.delete(near[0]) and database.logged() == 3  # nothing deleted, nothing pruned
