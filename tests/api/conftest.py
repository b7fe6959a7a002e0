"""A live app per test module, with the lifespan run (TestClient inside ``with``)."""

import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.main import create_app

UPLOAD_CAP = 2_000_000


@pytest.fixture(scope="module")
def client():
    settings = Settings(max_upload_bytes=UPLOAD_CAP, max_vertices=50_000, solver_concurrency=2)
    with TestClient(create_app(settings)) as test_client:
        yield test_client
