"""The SQLite store ranks from an in-memory copy of its features: every answer must still be the
one reading every row of the file gives, whoever wrote the file and however.

Two stores on one file stand for two processes of the service (each has its own copy); the
brute-force truth is computed from what the file holds, read directly.
"""

import sqlite3
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from app.retrieval.distance import nearest_of
from app.retrieval.store import SQLiteStore
from tests.retrieval.test_stores import spectra


def _truth(path, query: np.ndarray, top: int) -> list[str]:
    """The labels of the ``top`` stored shapes nearest ``query``, from every row of the file."""
    with sqlite3.connect(path) as connection:
        rows = connection.execute("SELECT label, spectrum FROM shapes ORDER BY rowid").fetchall()
    stored = np.stack([np.frombuffer(spectrum, dtype=np.float64) for _, spectrum in rows])
    order = np.argsort(nearest_of(query, stored)[0], kind="stable")[:top]
    return [rows[i][0] for i in order]


def _ids_by_rowid(path) -> list[str]:
    with sqlite3.connect(path) as connection:
        return [row[0] for row in connection.execute("SELECT id FROM shapes ORDER BY rowid")]


def test_every_answer_is_the_file_s_whatever_another_process_wrote(tmp_path):
    path = tmp_path / "shapes.sqlite"
    reader, writer = SQLiteStore(path), SQLiteStore(path)
    rng = np.random.default_rng(0)
    pool = spectra(400, 5)
    for step in range(60):
        ids = _ids_by_rowid(path)
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
        assert [m.record.label for m in reader.nearest(query, 7)] == _truth(path, query, 7), step


def test_a_file_of_an_earlier_version_is_ranked_and_its_deletions_seen(tmp_path):
    """A file made before the deletions count existed gets it on opening."""
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
    assert [m.record.label for m in store.nearest(query, 5)] == _truth(path, query, 5)


def test_an_empty_store_answers_nothing_and_then_its_first_shape(tmp_path):
    store = SQLiteStore(tmp_path / "empty.sqlite")
    assert store.nearest(spectra(1, 7)[0], 3) == []
    record = store.add("first", spectra(1, 8)[0], "test")
    assert [m.record.id for m in store.nearest(spectra(1, 7)[0], 3)] == [record.id]


def test_a_file_replaced_by_a_smaller_one_is_read_again(tmp_path):
    """A backup restored under a running service: no deletion was counted, but the rows are others."""
    path = tmp_path / "shapes.sqlite"
    store = SQLiteStore(path)
    store.add_many([f"old-{i}" for i in range(10)], spectra(10, 9), "test")
    query = spectra(1, 10)[0]
    assert store.nearest(query, 1)[0].record.label.startswith("old-")
    for leftover in tmp_path.glob("shapes.sqlite*"):
        leftover.unlink()
    SQLiteStore(path).add_many([f"new-{i}" for i in range(3)], spectra(3, 11), "test")
    assert [m.record.label for m in store.nearest(query, 3)] == _truth(path, query, 3)


def test_threads_ranking_while_another_inserts_all_get_the_file_s_answer(tmp_path):
    """The service's k-NN requests share one store from several threads while uploads add shapes:
    rows added far from the queries (three times the scale) never change their answer, so every
    answer, whatever snapshot its thread read, must be the one computed before; a worker's
    exception surfaces through its future."""
    path = tmp_path / "shapes.sqlite"
    store, writer = SQLiteStore(path), SQLiteStore(path)
    near = spectra(300, 12)
    store.add_many([f"near-{i}" for i in range(300)], near, "test")
    queries = near[:20] * 1.01
    expected = [_truth(path, query, 5) for query in queries]
    far = spectra(150, 13) * 3

    def rank(round_: int) -> list[list[str]]:
        return [[m.record.label for m in store.nearest(query, 5)] for query in queries[round_ % 2 :: 2]]

    with ThreadPoolExecutor(max_workers=4) as pool:
        answers = [pool.submit(rank, i) for i in range(12)]
        for i, spectrum in enumerate(far):
            writer.add(f"far-{i}", spectrum, "test")
        for i, answer in enumerate(answers):
            assert answer.result(timeout=60) == expected[i % 2 :: 2]
    assert store.count() == 450
    assert [m.record.label for m in store.nearest(far[7] * 1.01, 3)] == _truth(path, far[7] * 1.01, 3)
