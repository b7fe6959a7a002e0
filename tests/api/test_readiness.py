"""Readiness is the truth: broken artefacts or an unreachable database make the service not
ready, only the endpoints that need the broken part answer 503, and the rest keep working."""

import json
import shutil

import numpy as np
import pytest
from fastapi.testclient import TestClient

from app.core.config import Settings
from app.main import create_app
from harness.postgres import free_port
from tests.api.conftest import settings_for


def spectra_form() -> dict:
    lambdas = np.cumsum(np.linspace(1, 4, 20)) * 3
    return {"spectra": json.dumps([lambdas.tolist(), (lambdas * 1.2).tolist()])}


@pytest.fixture
def models_copy(tmp_path):
    target = tmp_path / "models"
    shutil.copytree(Settings().models_dir, target)
    return target


def app_with(tmp_path, **update) -> TestClient:
    settings = settings_for(tmp_path / "shapes.sqlite").model_copy(update=update)
    return TestClient(create_app(settings))


@pytest.mark.parametrize("damage", ["flip-a-byte", "delete"])
def test_a_damaged_model_file_makes_the_service_not_ready_and_its_endpoints_503(tmp_path, models_copy, damage):
    target = models_copy / "localizer.onnx"
    if damage == "delete":
        target.unlink()
    else:
        data = bytearray(target.read_bytes())
        data[len(data) // 2] ^= 0xFF
        target.write_bytes(bytes(data))
    with app_with(tmp_path, models_dir=models_copy) as client:
        assert client.get("/healthz").status_code == 200
        ready = client.get("/readyz")
        assert ready.status_code == 503 and "localizer.onnx" in ready.json()["detail"]
        for response in (client.post("/v1/union", data=spectra_form()), client.get("/v1/models")):
            assert response.status_code == 503
            assert response.json()["type"] == "/problems/models-unavailable"
            assert response.headers["retry-after"]
        assert client.get("/v1/shapes").status_code == 200  # the database needs no model


def test_models_trained_on_another_spectrum_definition_are_refused(tmp_path, models_copy):
    """A manifest stamped with another definition (or none: models from before the stamp) loads
    no model: its answers would be wrong for every request."""
    manifest = models_copy / "MANIFEST.json"
    content = json.loads(manifest.read_text())
    for stamp in ({**content["spectrum_definition"], "version": 0}, None):
        content["spectrum_definition"] = stamp
        manifest.write_text(json.dumps(content))
        with app_with(tmp_path, models_dir=models_copy) as client:
            ready = client.get("/readyz")
            assert ready.status_code == 503 and "spectrum definition" in ready.json()["detail"]
            assert client.post("/v1/union", data=spectra_form()).json()["type"] == "/problems/models-unavailable"


def test_a_setting_that_changes_the_spectrum_definition_serves_no_union(tmp_path):
    """Filling larger holes than the models' training spectra did changes every spectrum: the
    models are not served, and the reason names the setting."""
    with app_with(tmp_path, max_hole_edges=4) as client:
        ready = client.get("/readyz")
        assert ready.status_code == 503 and "SPECTRAL_UNIONS_MAX_HOLE_EDGES=4" in ready.json()["detail"]
        union = client.post("/v1/union", data=spectra_form())
        assert union.status_code == 503 and "max_hole_edges=8" in union.json()["detail"]
    with app_with(tmp_path) as client:
        assert client.post("/v1/union", data=spectra_form()).status_code == 200


def test_an_unreachable_database_leaves_the_spectral_endpoints_working(tmp_path):
    url = f"postgresql://nobody@127.0.0.1:{free_port()}/none"
    with app_with(tmp_path, database_url=url) as client:
        ready = client.get("/readyz")
        assert ready.status_code == 503 and "database" in ready.json()["detail"]
        shapes = client.get("/v1/shapes")
        assert shapes.status_code == 503 and shapes.json()["type"] == "/problems/database-unavailable"
        assert shapes.headers["retry-after"]
        union = client.post("/v1/union", data=spectra_form())
        assert union.status_code == 200 and len(union.json()["eigenvalues"]) == 20
        database = client.get("/v1/models").json()["database"]
        assert database["backend"] == "postgresql" and database["shapes"] is None and database["problem"]


def test_a_database_that_comes_back_is_used_without_a_restart(tmp_path):
    blocker = tmp_path / "not-a-folder"
    blocker.write_text("a file where the database folder should be")
    with app_with(tmp_path, database_path=blocker / "shapes.sqlite") as client:
        assert client.get("/v1/shapes").status_code == 503
        blocker.unlink()
        assert client.get("/v1/shapes").json()["total"] > 0  # opened and seeded on this request
        assert client.get("/readyz").status_code == 200


def test_start_up_logs_what_is_served_and_what_is_not(tmp_path, models_copy, caplog):
    caplog.set_level("INFO", logger="uvicorn.error")
    with app_with(tmp_path) as client:
        models = client.get("/v1/models").json()
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("spectral-unions"))
    assert f"models {models['model_version']} (k = {models['k']}, template of {models['template_vertices']}" in line
    assert f"with {models['database']['shapes']} shapes" in line
    caplog.clear()
    (models_copy / "union.onnx").unlink()
    with app_with(tmp_path, models_dir=models_copy):
        pass
    line = next(r.getMessage() for r in caplog.records if r.getMessage().startswith("spectral-unions"))
    assert "models unavailable" in line and "union.onnx" in line
