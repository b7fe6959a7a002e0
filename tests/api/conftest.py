"""A live app per test module, with the lifespan run (TestClient inside ``with``)."""

import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.main import create_app

UPLOAD_CAP = 2_000_000
API_KEY = "test-key-0123456789"


def settings_for(database) -> Settings:
    return Settings(
        max_upload_bytes=UPLOAD_CAP,
        max_vertices=50_000,
        solver_concurrency=2,
        database_path=database,
        api_key=API_KEY,
    )


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    database = tmp_path_factory.mktemp("db") / "shapes.sqlite"
    with TestClient(create_app(settings_for(database))) as test_client:
        yield test_client
