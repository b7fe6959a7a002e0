"""The pages the service serves itself: ``/`` (the scanning session, ``app/static/session``)
and ``/docs`` (Swagger UI from the vendored files in ``app/static/swagger-ui``).

FastAPI's default page loads Swagger UI from a CDN and its favicon from another host, so it
was blank without internet or behind a firewall. The page here names only paths of this
service; the files, their version and checksums are in ``app/static/swagger-ui/VENDORED.md``.
ReDoc is not offered: it too would come from a CDN. The session page's three.js is vendored
the same way (``app/static/vendor/three/VENDORED.md``).
"""

from pathlib import Path

from fastapi import FastAPI
from fastapi.openapi.docs import get_swagger_ui_html
from fastapi.responses import HTMLResponse
from fastapi.staticfiles import StaticFiles

from app.geometry.formats import accept_attribute, listed

STATIC_DIR = Path(__file__).resolve().parents[1] / "static"
STATIC_URL = "/static"
SWAGGER_URL = f"{STATIC_URL}/swagger-ui"


def session_page() -> str:
    """The session page, its file picker offering the accepted upload formats
    (:mod:`app.geometry.formats`): the page does not keep a list of its own."""
    page = (STATIC_DIR / "session" / "index.html").read_text()
    return page.replace("{formats}", listed()).replace("{accept}", accept_attribute())


def install_pages(app: FastAPI) -> None:
    """Serve the static files, the session page and the ``/docs`` page (the app is built with
    ``docs_url=None`` so FastAPI's CDN page is not registered)."""
    app.mount(STATIC_URL, StaticFiles(directory=STATIC_DIR), name="static")

    page = session_page()

    @app.get("/", include_in_schema=False)
    async def session() -> HTMLResponse:
        return HTMLResponse(page)

    @app.get("/docs", include_in_schema=False)
    async def docs() -> HTMLResponse:
        return get_swagger_ui_html(
            openapi_url=app.openapi_url or "/openapi.json",
            title=f"{app.title} — API",
            swagger_js_url=f"{SWAGGER_URL}/swagger-ui-bundle.js",
            swagger_css_url=f"{SWAGGER_URL}/swagger-ui.css",
            swagger_favicon_url=f"{SWAGGER_URL}/favicon-32x32.png",
            # No "valid" badge: it is an image fetched from validator.swagger.io.
            swagger_ui_parameters={"validatorUrl": None},
        )
