"""The compose topology holds together: names, ports, caps and health gates agree across files.

Docker cannot run here (tests/api/test_replicas.py runs the same topology as processes); this
catches the edits that would only fail at ``docker compose up``.
"""

import re
from pathlib import Path

import yaml

from app.core.config import Settings

ROOT = Path(__file__).resolve().parents[1]


def compose() -> dict:
    return yaml.safe_load((ROOT / "docker-compose.yml").read_text())


def nginx() -> str:
    return (ROOT / "deploy" / "nginx.conf").read_text()


def test_two_api_replicas_behind_the_proxy_and_one_database():
    services = compose()["services"]
    assert services["api"]["deploy"]["replicas"] == 2
    assert "ports" not in services["api"]  # only the proxy is published
    assert services["api"]["depends_on"]["db"]["condition"] == "service_healthy"
    assert services["proxy"]["depends_on"]["api"]["condition"] == "service_healthy"
    assert "healthcheck" in services["db"] and "healthcheck" in services["proxy"]


def test_the_api_health_check_needs_no_curl_and_asks_for_readiness():
    dockerfile = (ROOT / "Dockerfile").read_text()
    check = dockerfile[dockerfile.index("HEALTHCHECK") :].split("\n\n")[0]
    assert "/readyz" in check and "curl" not in check


def test_the_proxy_reaches_the_api_on_the_port_it_serves():
    served = re.search(r'"--port", "(\d+)"', (ROOT / "Dockerfile").read_text())
    upstream = re.search(r"server api:(\d+)", nginx())
    assert served and upstream and served.group(1) == upstream.group(1)
    published = compose()["services"]["proxy"]["ports"][0].rsplit(":", 1)[1]
    assert f"listen {published};" in nginx()


def test_the_api_reads_the_compose_database_and_its_caps_fit_the_proxy():
    environment = compose()["services"]["api"]["environment"]
    url = environment["SPECTRAL_UNIONS_DATABASE_URL"].replace("${POSTGRES_PASSWORD:-spectral}", "secret")
    settings = Settings(database_url=url, max_upload_bytes=int(environment["SPECTRAL_UNIONS_MAX_UPLOAD_BYTES"]))
    assert "@db:5432/" in settings.database_url
    proxy_cap = int(re.search(r"client_max_body_size (\d+)m;", nginx()).group(1)) * 2**20
    assert proxy_cap > settings.max_upload_bytes
