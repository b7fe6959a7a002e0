"""``/docs`` works offline: the page names only this service's paths, and they serve the
vendored Swagger UI files whose checksums ``VENDORED.md`` records."""

import hashlib
import re

from app.api.pages import STATIC_DIR


def test_the_docs_page_loads_nothing_from_another_host(client):
    page = client.get("/docs")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    sources = re.findall(r"""(?:src|href)=["']([^"']+)["']""", page.text)
    assert len(sources) >= 3
    assert all(source.startswith("/") for source in sources), sources
    assert "validatorUrl" in page.text and "cdn" not in page.text.lower()
    for source in sources:
        asset = client.get(source)
        assert asset.status_code == 200 and len(asset.content) > 0, source
    assert "openapi" in client.get("/openapi.json").json()


def test_the_vendored_files_are_the_recorded_release():
    folder = STATIC_DIR / "swagger-ui"
    recorded = dict(
        (name, digest)
        for digest, name in re.findall(r"^([0-9a-f]{64})  (\S+)$", (folder / "VENDORED.md").read_text(), re.MULTILINE)
    )
    assert set(recorded) == {"swagger-ui-bundle.js", "swagger-ui.css", "favicon-32x32.png"}
    for name, digest in recorded.items():
        assert hashlib.sha256((folder / name).read_bytes()).hexdigest() == digest, name
    assert "Apache License" in (folder / "LICENSE").read_text()
