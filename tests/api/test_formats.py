"""One list of upload formats (``app/geometry/formats.py``) is what every reader of it shows: the
parser accepts exactly those types and names them all when it refuses another, the session page
offers them, the routes describe them and the docs' table is the list's own rendering."""

import re
from pathlib import Path

import pytest

from app.geometry.errors import UnsupportedFileType
from app.geometry.formats import FORMATS, markdown_table
from app.geometry.io import resolve_file_type

NAMES = [f.name for f in FORMATS]
DOCS = Path(__file__).resolve().parents[2] / "docs" / "api.md"


@pytest.mark.parametrize("name", NAMES)
def test_every_listed_type_is_read_by_extension_and_by_name(name):
    assert resolve_file_type(f"scan.{name.upper()}") == name
    assert resolve_file_type("scan.bin", name) == name


@pytest.mark.parametrize("other", ["zip", "gltf", "ply.gz", "", "exe"])
def test_any_other_type_is_refused_naming_every_listed_one(other):
    with pytest.raises(UnsupportedFileType) as refused:
        resolve_file_type(f"scan.{other}" if other else "scan")
    assert re.findall(r"\w+", str(refused.value).split("allowed:")[1]) == NAMES


def test_the_session_page_offers_the_listed_types(client):
    page = client.get("/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    accept = re.search(r'<input id="file" type="file" accept="([^"]*)"', page.text)
    assert accept is not None and accept.group(1).split(",") == [f".{name}" for name in NAMES]
    assert "{formats}" not in page.text and "{accept}" not in page.text


def test_the_upload_routes_describe_the_listed_types(client):
    schema = client.get("/openapi.json").json()
    described = [
        field["description"]
        for component in schema["components"]["schemas"].values()
        for name, field in component.get("properties", {}).items()
        if name in ("file", "files") and "description" in field
    ]
    assert len(described) >= 8
    assert all(description.endswith(", ".join(NAMES)) for description in described)


def test_the_docs_table_is_the_list_rendered():
    text = DOCS.read_text()
    block = text[
        text.index("<!-- formats:begin -->\n") + len("<!-- formats:begin -->\n") : text.index("<!-- formats:end -->")
    ]
    assert block.strip() == markdown_table()
    assert [row.split("`")[1] for row in block.strip().splitlines()[2:]] == NAMES
