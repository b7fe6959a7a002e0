"""Both ShapeDNA stores, for real: SQLite on a temporary file, PostgreSQL on a throw-away server."""

import numpy as np
import pytest

from app.contract import SEED_BODIES_FILE
from app.retrieval.distance import distances
from app.retrieval.seed import AT_REST_SPREAD, open_store
from app.retrieval.store import StoredBody


def spectra(count: int, seed: int) -> np.ndarray:
    rng = np.random.default_rng(seed)
    values = np.sort(rng.uniform(1, 80, (count, 20)), axis=1)
    values[:, 0] = 0  # complete bodies: closed surfaces, λ₁ = 0
    return values


@pytest.fixture(params=["sqlite", "postgresql"])
def store(request, tmp_path):
    if request.param == "sqlite":
        return open_store(tmp_path / "shapes.sqlite", None, tmp_path)
    return open_store(tmp_path / "unused.sqlite", request.getfixturevalue("fresh_postgres"), tmp_path)


def test_add_page_count_delete(store):
    stored = spectra(5, 0)
    records = [store.add(f"person-{i}", s, "test") for i, s in enumerate(stored)]
    assert store.count() == 5
    listed = store.page(0, 3) + store.page(3, 3)
    assert sorted(r.id for r in listed) == sorted(r.id for r in records)
    by_id = {r.id: r for r in listed}
    np.testing.assert_array_equal(by_id[records[2].id].spectrum, stored[2])
    assert store.delete(records[0].id) and not store.delete(records[0].id)
    assert store.count() == 4


def test_nearest_matches_brute_force_ranking(store):
    stored = spectra(200, 1)
    store.add_many([f"person-{i}" for i in range(200)], stored, "test")
    query = stored[17] * 1.02
    matches = store.nearest(query, 10)
    expected = np.argsort(distances(query, stored))[:10]
    assert [m.record.label for m in matches] == [f"person-{i}" for i in expected]
    np.testing.assert_allclose([m.distance for m in matches], np.sort(distances(query, stored))[:10], rtol=1e-9)


def test_nearest_to_any_of_several_spectra_is_each_shape_at_its_nearest(store):
    """Several queries (as /v1/retrieve's share profile asks): each stored shape ranked by its
    distance to the nearest of them, and told which one, as a brute-force minimum says."""
    stored = spectra(200, 3)
    store.add_many([f"person-{i}" for i in range(200)], stored, "test")
    queries = np.stack([stored[5] * 1.03, stored[60] * 0.97, stored[140] * 1.01, spectra(1, 4)[0]])
    each = np.stack([distances(query, stored) for query in queries])
    expected = np.argsort(each.min(axis=0), kind="stable")[:12]
    matches = store.nearest(queries, 12)
    assert [m.record.label for m in matches] == [f"person-{i}" for i in expected]
    np.testing.assert_allclose([m.distance for m in matches], each.min(axis=0)[expected], rtol=1e-9)
    assert [m.query for m in matches] == list(each.argmin(axis=0)[expected])
    assert {m.query for m in matches} >= {0, 1, 2}  # every near query contributes its own shapes


def test_seed_fills_only_an_empty_store(tmp_path, request):
    seed = spectra(4, 2)
    np.savez(tmp_path / "shapes.npz", labels=np.array(["a", "b", "c", "d"]), spectra=seed)
    first = open_store(tmp_path / "s.sqlite", None, tmp_path)
    assert first.count() == 4
    again = open_store(tmp_path / "s.sqlite", None, tmp_path)
    assert again.count() == 4


def test_a_shape_stored_with_a_body_gives_it_back_until_deleted(store):
    """Bodies come back as stored, with their labels and spreads; a shape without one has none;
    deleting a shape deletes its body."""
    coefficients = np.arange(24, dtype=np.float64) / 7
    with_body = store.add("ann", spectra(1, 3)[0], "ann.ply", StoredBody(coefficients, 0.4))
    store.add("bob", spectra(1, 4)[0], "bob.ply")
    store.add_many(
        ["cy", "dee"], spectra(2, 5), "seed", [StoredBody(-coefficients, 0.1), StoredBody(coefficients, 0.1)]
    )
    bodies = store.bodies()
    assert sorted(bodies.labels) == ["ann", "cy", "dee"] and with_body.id in bodies.ids
    ann = bodies.ids.index(with_body.id)
    np.testing.assert_array_equal(bodies.coefficients[ann], coefficients)
    assert bodies.spread[ann] == 0.4 and sorted(bodies.spread.tolist()) == [0.1, 0.1, 0.4]
    assert store.delete(with_body.id)
    assert sorted(store.bodies().labels) == ["cy", "dee"]


def test_the_seed_stores_each_person_s_body_at_rest(tmp_path):
    np.savez(tmp_path / "shapes.npz", labels=np.array(["a", "b", "a"]), spectra=spectra(3, 6))
    np.savez(tmp_path / SEED_BODIES_FILE, labels=np.array(["b", "a"]), coefficients=np.array([[1.0, 2.0], [3.0, 4.0]]))
    bodies = open_store(tmp_path / "s.sqlite", None, tmp_path).bodies()
    rows = sorted(zip(bodies.labels, bodies.coefficients.tolist(), strict=True))
    assert rows == [("a", [3.0, 4.0]), ("a", [3.0, 4.0]), ("b", [1.0, 2.0])]
    assert set(bodies.spread.tolist()) == {AT_REST_SPREAD}


def test_postgres_reuses_connections_across_a_server_restart(tmp_path):
    """Idle connections kept for reuse die with the server: the next call after a restart must
    find that out and reconnect, not fail; a call while the server is down is unavailable."""
    from app.retrieval.store import StoreUnavailable
    from harness.postgres import ThrowawayPostgres

    try:
        server = ThrowawayPostgres()
    except FileNotFoundError as exc:
        pytest.skip(str(exc))
    server.start()
    try:
        store = open_store(tmp_path / "unused.sqlite", server.url, tmp_path)
        store.add("someone", spectra(1, 3)[0], "test")  # leaves an idle connection behind
        server.stop()
        server.start()
        assert store.count() == 1  # the dead idle connection was replaced, no error
        server.stop()
        with pytest.raises(StoreUnavailable):
            store.count()
        server.start()
        assert store.count() == 1
        store.close()
    finally:
        server.remove()
