"""The compose topology without Docker: two API processes on loopback sharing one PostgreSQL.

What scale-out promises: a shape written through one replica is retrieved through the other,
and replicas starting together seed the shared database once, not once each.
"""

from collections.abc import Iterator

import httpx
import psycopg
import pytest

from harness.postgres import free_port
from harness.servers import start, wait_ready
from tests.api.conftest import API_KEY
from tests.api.test_shapes_api import body_ply


@pytest.fixture(scope="module")
def replicas(postgres_url) -> Iterator[list[str]]:
    with psycopg.connect(postgres_url, autocommit=True) as connection:
        connection.execute("DROP TABLE IF EXISTS shapes")
    ports = [free_port(), free_port()]
    processes = [start(port, {"SPECTRAL_UNIONS_DATABASE_URL": postgres_url}) for port in ports]
    bases = [f"http://127.0.0.1:{port}" for port in ports]
    try:
        for base, process in zip(bases, processes, strict=True):
            wait_ready(base, process)
        yield bases
    finally:
        for process in processes:
            process.terminate()
            process.wait(timeout=20)


def test_replicas_seed_the_shared_database_once(replicas):
    totals = [httpx.get(f"{base}/v1/shapes", params={"limit": 1}).json()["total"] for base in replicas]
    models = httpx.get(f"{replicas[0]}/v1/models").json()
    assert totals[0] == totals[1] > 0
    assert models["database"]["backend"] == "postgresql"
    assert models["database"]["shapes"] == totals[0]


def test_a_shape_added_through_one_replica_is_retrieved_through_the_other(replicas):
    first, second = replicas
    files = {"file": ("body.ply", body_ply(1.07), "application/octet-stream")}
    added = httpx.post(
        f"{first}/v1/shapes", files=files, data={"label": "replica-probe"}, headers={"X-API-Key": API_KEY}, timeout=60
    )
    assert added.status_code == 201, added.text
    shape = added.json()
    found = httpx.post(
        f"{second}/v1/retrieve", data={"spectra": f"[{shape['spectrum']}]"}, params={"top": 1}, timeout=60
    ).json()
    assert found["matches"][0]["id"] == shape["id"]
    assert found["matches"][0]["label"] == "replica-probe"
    assert found["matches"][0]["distance"] == pytest.approx(0.0, abs=1e-9)
    deleted = httpx.delete(f"{second}/v1/shapes/{shape['id']}", headers={"X-API-Key": API_KEY})
    assert deleted.status_code == 204
    assert httpx.delete(f"{first}/v1/shapes/{shape['id']}", headers={"X-API-Key": API_KEY}).status_code == 404
