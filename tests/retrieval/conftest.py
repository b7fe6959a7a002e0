"""Store tests run on both engines; ``postgres_url`` (tests/conftest.py) is the throw-away server."""

import psycopg
import pytest


@pytest.fixture
def fresh_postgres(postgres_url):
    """The server with no shapes or deletion log: each test starts from an empty database."""
    with psycopg.connect(postgres_url, autocommit=True) as connection:
        connection.execute("DROP TABLE IF EXISTS shapes, deleted_shapes, shape_bodies")
    return postgres_url
