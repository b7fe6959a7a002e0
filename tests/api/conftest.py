"""A live app per test module, with the lifespan run (TestClient inside ``with``)."""

import shutil
from pathlib import Path

import pytest
from fastapi.testclient import TestClient

from app.contract import SESSIONS_FILE
from app.core.config import Settings
from app.inference.manifest import write_manifest
from app.inference.template import Template
from app.main import create_app
from app.samples import PARTS, template_part
from harness.servers import API_KEY

UPLOAD_CAP = 2_000_000


def settings_for(database) -> Settings:
    return Settings(
        max_upload_bytes=UPLOAD_CAP,
        max_vertices=50_000,
        solver_concurrency=2,
        database_path=database,
        api_key=API_KEY,
    )


def settings_without(tmp_path: Path, artefact: str) -> Settings:
    """Test settings serving a copy of the models without one optional ``artefact`` (and its
    manifest without it): what a models folder that never had it serves."""
    models = tmp_path / "models"
    shutil.copytree(Settings().models_dir, models)
    (models / artefact).unlink()
    write_manifest(models)
    return settings_for(tmp_path / "shapes.sqlite").model_copy(update={"models_dir": models})


@pytest.fixture(scope="module")
def client(tmp_path_factory):
    database = tmp_path_factory.mktemp("db") / "shapes.sqlite"
    with TestClient(create_app(settings_for(database))) as test_client:
        yield test_client


@pytest.fixture(scope="module")
def chain_client(tmp_path_factory):
    """A live app serving the models without the sessions' calibration: every union, of uploads
    too, is the learned operator's fold, told what the uploads' places or footprints say (what a
    models folder without ``sessions.json`` serves, and what a union of spectra always gets)."""
    settings = settings_without(tmp_path_factory.mktemp("chain"), SESSIONS_FILE)
    with TestClient(create_app(settings)) as test_client:
        yield test_client


@pytest.fixture(scope="module")
def template() -> Template:
    return Template.load(Settings().models_dir)


@pytest.fixture(scope="module")
def samples(template) -> dict[str, bytes]:
    """The README's sample parts, cut from the template."""
    return {name: template_part(template, removed) for name, removed in PARTS.items()}


def correspond(client, name: str, data: bytes, **params):
    """One upload placed by ``POST /v1/correspondence``."""
    return client.post("/v1/correspondence", params=params, files={"file": (name, data)})
