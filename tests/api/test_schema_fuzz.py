"""Schemathesis against the service's own OpenAPI schema, on a live server: no 500s, every response as documented.

The schema is the app's own (no server needed to collect the tests); the cases are sent to a
real ``spectral-unions serve`` process, so the lifespan, the solver workers and the limits all
take part, and every check schemathesis has is applied to every answer.
"""

import pytest
import schemathesis
from hypothesis import HealthCheck, settings

from app.main import create_app
from harness.postgres import free_port
from harness.servers import start, wait_ready
from tests.api.conftest import API_KEY

# A schema-valid request is not always a valid shape: any bytes satisfy ``format: binary`` and
# any string the ``spectra`` field, so for positive data a 415 (file type) or 422 (the bytes or
# the JSON say no) is an acceptance of the request, not a rejection of valid data.
CONFIG = schemathesis.Config.from_dict(
    {"checks": {"positive_data_acceptance": {"expected-statuses": ["2XX", "401", "403", "404", "415", "422"]}}}
)
schema = schemathesis.openapi.from_dict(create_app().openapi(), config=CONFIG)


@pytest.fixture(scope="module")
def live_base(tmp_path_factory):
    port = free_port()
    base = f"http://127.0.0.1:{port}"
    database = tmp_path_factory.mktemp("fuzz") / "shapes.sqlite"
    process = start(port, {"SPECTRAL_UNIONS_DATABASE_PATH": str(database)})
    try:
        wait_ready(base, process)
        yield base
    finally:
        process.terminate()
        process.wait(timeout=30)


@schema.parametrize()
@settings(max_examples=40, deadline=None, suppress_health_check=list(HealthCheck))
def test_every_operation_answers_as_documented(case, live_base):
    case.call_and_validate(base_url=live_base, headers={"X-API-Key": API_KEY}, timeout=60)
