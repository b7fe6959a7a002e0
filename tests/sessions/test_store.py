"""The sessions' store on both engines: a view comes back as it went in, views added at once all
land, a full or expired session refuses a view and stays as it was, and the union cache serves
only the views it was read from."""

import threading
import time

import numpy as np
import psycopg
import pytest

from app.inference.cover import Cover
from app.inference.models import UnionEstimate
from app.sessions.chain import Located
from app.sessions.fused import View
from app.sessions.records import SessionFull, SessionNotFound
from app.sessions.session import SessionUnion, SessionView
from app.sessions.store import open_sessions

TEMPLATE_VERTICES = 100
DAY = 24 * 3600.0


def a_view(seed: int, mesh: bool = True) -> SessionView:
    rng = np.random.default_rng(seed)
    points = rng.normal(size=(50, 3))
    boundary = rng.random(50) < 0.2
    faces = rng.integers(0, 50, size=(30, 3)) if mesh else None
    geometry = View(points, rng.random(50) * 1e-3, boundary, rng.integers(0, 50, size=(7, 2)), faces)
    region = rng.random(TEMPLATE_VERTICES) < 0.3
    located = Located(Cover(region, region.astype(float)), float(rng.random()), float(rng.random()))
    values = np.sort(rng.random(20) * 100)
    places = rng.normal(size=(50, 3))
    return SessionView(f"view{seed}.ply", values, geometry, places, located, (f"warning {seed}",))


@pytest.fixture(params=["sqlite", "postgresql"])
def store_for(request, tmp_path):
    """A factory of session stores on one engine's fresh database, with their time-to-live."""
    if request.param == "sqlite":
        return lambda ttl=DAY: open_sessions(tmp_path / "sessions.sqlite", None, ttl)
    url = request.getfixturevalue("postgres_url")
    with psycopg.connect(url, autocommit=True) as connection:
        connection.execute("DROP TABLE IF EXISTS scan_session_views, scan_sessions")
    return lambda ttl=DAY: open_sessions(tmp_path, url, ttl)


def test_a_view_comes_back_as_it_went_in(store_for):
    store = store_for()
    meta = store.create(True, "mm", None)
    sent = a_view(1)
    assert store.add_view(meta.id, sent, 32).views == 1
    read, (back,) = store.views(meta.id, TEMPLATE_VERTICES)
    assert (read.id, read.registered, read.units, read.scale, read.views) == (meta.id, True, "mm", None, 1)
    assert back.source == sent.source and back.warnings == sent.warnings
    np.testing.assert_array_equal(back.eigenvalues, sent.eigenvalues)
    np.testing.assert_allclose(back.geometry.points, sent.geometry.points, rtol=1e-6)  # float32 on disk
    np.testing.assert_allclose(back.geometry.mass, sent.geometry.mass, rtol=1e-6)
    np.testing.assert_array_equal(back.geometry.boundary, sent.geometry.boundary)
    np.testing.assert_array_equal(back.geometry.edges, sent.geometry.edges)
    np.testing.assert_array_equal(back.geometry.faces, sent.geometry.faces)
    np.testing.assert_allclose(back.places, sent.places, rtol=1e-6)
    np.testing.assert_array_equal(back.located.cover.region, sent.located.cover.region)
    assert back.located.confidence == sent.located.confidence and back.located.area == sent.located.area


def test_a_point_cloud_view_comes_back_without_faces(store_for):
    store = store_for()
    meta = store.create(False, "m", None)
    store.add_view(meta.id, a_view(2, mesh=False), 32)
    _, (back,) = store.views(meta.id, TEMPLATE_VERTICES)
    assert back.geometry.faces is None


def test_views_added_at_once_all_land_in_one_order(store_for):
    store = store_for()
    session = store.create(False, "m", None).id
    errors: list[BaseException] = []

    def add(seed: int) -> None:
        try:
            store.add_view(session, a_view(seed), 32)
        except BaseException as exc:  # noqa: BLE001 (reported below)
            errors.append(exc)

    threads = [threading.Thread(target=add, args=(seed,)) for seed in range(8)]
    for thread in threads:
        thread.start()
    for thread in threads:
        thread.join()
    assert not errors
    meta, views = store.views(session, TEMPLATE_VERTICES)
    assert meta.views == 8 and sorted(view.source for view in views) == sorted(f"view{s}.ply" for s in range(8))


def test_a_full_session_refuses_a_view_and_stays_as_it_was(store_for):
    store = store_for()
    session = store.create(False, "m", None).id
    store.add_view(session, a_view(1), 2)
    store.add_view(session, a_view(2), 2)
    with pytest.raises(SessionFull):
        store.add_view(session, a_view(3), 2)
    meta, views = store.views(session, TEMPLATE_VERTICES)
    assert meta.views == 2 and [view.source for view in views] == ["view1.ply", "view2.ply"]


def test_an_untouched_session_expires_and_a_missing_one_is_not_found(store_for):
    store = store_for(ttl=0.5)
    session = store.create(False, "m", None).id
    store.add_view(session, a_view(1), 32)
    time.sleep(0.7)
    for read in (store.meta, lambda s: store.views(s, TEMPLATE_VERTICES), lambda s: store.add_view(s, a_view(2), 32)):
        with pytest.raises(SessionNotFound):
            read(session)
    store.create(False, "m", None)  # sweeps the expired session away, views and all
    assert not store.delete(session)
    with pytest.raises(SessionNotFound):
        store.meta("no-such-session")


def test_the_cached_union_serves_only_the_views_and_models_it_was_read_from(store_for):
    store = store_for()
    session = store.create(False, "m", None).id
    store.add_view(session, a_view(1), 32)
    union = SessionUnion(UnionEstimate(np.arange(1.0, 4.0), np.full(3, 0.5), (True,)), "learned-chain", [0.3], [True])
    store.cache_union(session, 1, "models-a", union)
    cached = store.cached_union(session, 1, "models-a")
    np.testing.assert_array_equal(cached.estimate.eigenvalues, union.estimate.eigenvalues)
    np.testing.assert_array_equal(cached.estimate.sigma, union.estimate.sigma)
    assert (cached.union_by, cached.overlaps, cached.overlaps_told, cached.estimate.nested) == (
        "learned-chain",
        [0.3],
        [True],
        (True,),
    )
    assert store.cached_union(session, 1, "models-b") is None
    store.add_view(session, a_view(2), 32)
    assert store.cached_union(session, 2, "models-a") is None
    late = SessionUnion(UnionEstimate(np.arange(5.0, 8.0), np.zeros(3)), "view")
    store.cache_union(session, 1, "models-a", late)  # read from 1 view, the session has 2 by now: not kept
    np.testing.assert_array_equal(store.cached_union(session, 1, "models-a").estimate.eigenvalues, [1.0, 2.0, 3.0])
    assert store.cached_union(session, 2, "models-a") is None


def test_an_ended_session_is_gone(store_for):
    store = store_for()
    session = store.create(False, "m", None).id
    store.add_view(session, a_view(1), 32)
    assert store.delete(session) and not store.delete(session)
    with pytest.raises(SessionNotFound):
        store.views(session, TEMPLATE_VERTICES)


def test_a_service_key_is_made_once_and_shared_by_every_opening(store_for):
    """Two openings of one database (two replicas) read the same key; another name, another key."""
    first, second = store_for(), store_for()
    key = first.service_key("region-tokens")
    assert len(key) == 32 and second.service_key("region-tokens") == key == first.service_key("region-tokens")
    assert second.service_key("something-else") != key
