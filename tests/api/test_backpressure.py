"""Overfilling the solve queue: exactly the excess is refused at once, the admitted rest is served.

As Triton's queue tests do, the slot is occupied on purpose (the test holds the only solve
slot, as a long solve would), so the count of rejections is exact rather than a matter of
timing: one running place plus ``QUEUE`` waiting places are admitted, the rest refused.
"""

import threading
import time

import pytest
import trimesh
from fastapi.testclient import TestClient

from app.main import create_app
from tests.api.conftest import settings_for
from tests.conftest import bumpy_patch

QUEUE = 2
SENT = 6
ADMITTED = 1 + QUEUE  # solver_concurrency = 1


def patch_ply() -> bytes:
    mesh = bumpy_patch(seed=4, n=400)
    return trimesh.Trimesh(mesh.vertices, mesh.faces, process=False).export(file_type="ply")


@pytest.fixture
def busy_client(tmp_path):
    settings = settings_for(tmp_path / "shapes.sqlite").model_copy(
        update={"solver_concurrency": 1, "max_queued_solves": QUEUE}
    )
    with TestClient(create_app(settings)) as client:
        yield client


def _waiting(client: TestClient) -> int:
    return client.app.state.solver.limiter.statistics().tasks_waiting


def test_a_full_queue_sheds_exactly_the_excess_with_a_retry_hint(busy_client):
    limiter = busy_client.app.state.solver.limiter
    holder = object()
    busy_client.portal.call(limiter.acquire_on_behalf_of_nowait, holder)
    body = patch_ply()
    responses: list = []

    def post() -> None:
        responses.append(busy_client.post("/v1/spectrum", files={"file": ("patch.ply", body)}))

    threads = [threading.Thread(target=post) for _ in range(SENT)]
    for thread in threads:
        thread.start()
    deadline = time.monotonic() + 30
    while (len(responses) < SENT - ADMITTED or _waiting(busy_client) < ADMITTED) and time.monotonic() < deadline:
        time.sleep(0.01)
    refused = list(responses)
    busy_client.portal.call(limiter.release_on_behalf_of, holder)
    for thread in threads:
        thread.join(timeout=60)

    assert len(refused) == SENT - ADMITTED
    for response in refused:
        assert response.status_code == 503
        assert response.headers["retry-after"] == "1"
        assert response.json()["type"] == "/problems/overloaded"
    served = [r for r in responses if r not in refused]
    assert len(served) == ADMITTED and all(r.status_code == 200 for r in served)
