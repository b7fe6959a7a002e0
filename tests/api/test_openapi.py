"""The OpenAPI page documents every error as the one problem+json shape, with an example, and
the errors table of docs/operating.md names every problem type the service can answer."""

import json
import re
from pathlib import Path

from fastapi.testclient import TestClient
from pydantic import TypeAdapter

from app.api.problems import EXAMPLES, FRAMEWORK_PROBLEMS
from app.core.config import Settings
from app.core.errors import InputError
from app.main import create_app
from tests.api.conftest import API_KEY


def test_every_documented_error_is_a_problem_with_an_example():
    schema = create_app().openapi()
    checked = 0
    for path, operations in schema["paths"].items():
        for method, operation in operations.items():
            for status, response in operation["responses"].items():
                if status.startswith("2") or path in ("/healthz", "/readyz"):
                    continue
                content = response["content"]
                assert list(content) == ["application/problem+json"], (method, path, status)
                examples = content["application/problem+json"]["examples"]
                assert examples, (method, path, status)
                assert all(e["value"]["status"] == int(status) for e in examples.values())
                checked += 1
    assert checked >= 20


def _subclasses(cls: type) -> set[type]:
    return {cls} | {grand for sub in cls.__subclasses__() for grand in _subclasses(sub)}


def test_the_errors_table_names_every_problem_type():
    operating = (Path(__file__).resolve().parents[2] / "docs" / "operating.md").read_text()
    table = operating[operating.index("## Errors") : operating.index("## Configuration")]
    listed = set(re.findall(r"^\| \d{3} \| `([a-z-]+)` \|", table, re.MULTILINE))
    raised = {error.slug for error in _subclasses(InputError)}
    documented = {slug for examples in EXAMPLES.values() for slug, _, _ in examples}
    framework = {slug for status, (slug, _) in FRAMEWORK_PROBLEMS.items() if status == 400}
    assert raised | documented | framework <= listed, sorted((raised | documented | framework) - listed)


def test_every_response_field_is_described():
    schemas = create_app().openapi()["components"]["schemas"]
    responses = {name: schema for name, schema in schemas.items() if not name.startswith(("Body_", "HTTPValidation"))}
    undescribed = [
        f"{name}.{field}"
        for name, schema in responses.items()
        if name != "ValidationError"
        for field, spec in schema.get("properties", {}).items()
        if "description" not in spec
    ]
    assert not undescribed, undescribed


def _reproducers() -> dict:
    """For each documented example, a request that gets it, on an app with the default caps."""
    nan_ply = b"ply\nformat ascii 1.0\nelement vertex 3\nproperty float x\nproperty float y\nproperty float z\n"
    nan_ply += b"element face 1\nproperty list uchar int vertex_indices\nend_header\nnan 0 0\n1 0 0\n0 1 0\n3 0 1 2\n"
    faces_ply = nan_ply.replace(b"element face 1", b"element face 900000000")
    ascending = json.dumps([list(range(1, 21)), list(range(20, 0, -1))])
    return {
        "invalid-api-key": lambda c: c.delete("/v1/shapes/x", headers={"X-API-Key": "wrong"}),
        "shape-not-found": lambda c: c.delete("/v1/shapes/3f2a9c", headers={"X-API-Key": API_KEY}),
        "upload-too-large": lambda c: c.post("/v1/spectrum", headers={"content-length": str(2**26 + 1)}),
        "unsupported-file-type": lambda c: c.post("/v1/spectrum", files={"file": ("scan.zip", b"PK")}),
        "invalid-spectrum": lambda c: c.post("/v1/union", data={"spectra": ascending}),
        "invalid-geometry": lambda c: c.post("/v1/union", files={"files": ("scan.ply", nan_ply)}),
        "invalid-request": lambda c: c.post("/v1/retrieve", params={"top": 101}, data={"spectra": ascending}),
        "too-many-faces": lambda c: c.post("/v1/union", files={"files": ("scan.ply", faces_ply)}),
    }


def test_documented_error_examples_are_the_messages_the_service_sends(tmp_path):
    settings = Settings(database_path=tmp_path / "shapes.sqlite", api_key=API_KEY)  # the default caps
    documented = {slug: (status, detail) for status, rows in EXAMPLES.items() for slug, _, detail in rows}
    reproducers = _reproducers()
    with TestClient(create_app(settings)) as client:
        for slug, request in reproducers.items():
            response = request(client)
            assert (response.status_code, response.json()["detail"]) == documented[slug], slug
    unkeyed = Settings(database_path=tmp_path / "other.sqlite")
    with TestClient(create_app(unkeyed)) as client:
        response = client.delete("/v1/shapes/x", headers={"X-API-Key": "any"})
        assert (response.status_code, response.json()["detail"]) == documented["writes-disabled"]


def test_every_json_answer_has_a_success_example_that_its_model_accepts():
    """Each route's recorded answer (``app/api/examples.json``) is one its response model accepts,
    with every field, and the OpenAPI page shows it (less its nulls, which FastAPI leaves out of
    the page)."""
    from app.api.examples import EXAMPLES_FILE
    from app.api.responses import UnionResponse
    from app.api.routes.correspondence import CorrespondenceResponse
    from app.api.routes.localize import LocalizeResponse
    from app.api.routes.models import ModelsResponse
    from app.api.routes.overlap import OverlapResponse
    from app.api.routes.reconstruct import ReconstructResponse
    from app.api.routes.retrieve import RetrieveResponse
    from app.api.routes.shapes import AddedShape, ShapePage
    from app.geometry.pipeline import SpectrumReport

    models = {
        ("post", "/v1/spectrum", "200"): ("spectrum", SpectrumReport),
        ("post", "/v1/union", "200"): ("union", UnionResponse),
        ("post", "/v1/correspondence", "200"): ("correspondence", CorrespondenceResponse),
        ("post", "/v1/overlap", "200"): ("overlap", OverlapResponse),
        ("post", "/v1/localize", "200"): ("localize", LocalizeResponse),
        ("post", "/v1/reconstruct", "200"): ("reconstruct", ReconstructResponse),
        ("post", "/v1/retrieve", "200"): ("retrieve", RetrieveResponse),
        ("post", "/v1/shapes", "201"): ("add_shape", AddedShape),
        ("get", "/v1/shapes", "200"): ("list_shapes", ShapePage),
        ("get", "/v1/models", "200"): ("models", ModelsResponse),
    }
    recorded = json.loads(EXAMPLES_FILE.read_text())
    paths = create_app().openapi()["paths"]
    for (method, path, status), (name, model) in models.items():
        example = recorded[name]
        TypeAdapter(model).validate_python(example, strict=False)
        assert set(example) == set(TypeAdapter(model).json_schema()["properties"]), path
        shown = paths[path][method]["responses"][status]["content"]["application/json"]["example"]
        assert shown == without_nulls(example), path


def without_nulls(value):
    """``value`` as FastAPI writes it into the OpenAPI page: null fields left out, at every depth."""
    if isinstance(value, dict):
        return {key: without_nulls(item) for key, item in value.items() if item is not None}
    if isinstance(value, list):
        return [without_nulls(item) for item in value]
    return value
