"""``/v1/union``, ``/v1/localize`` and ``/v1/models`` on the committed ONNX models."""

import math

import numpy as np
import pytest

from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from app.geometry.topology import drop_unreferenced
from app.inference.template import PART_NAMES, Template

PROBLEM = "application/problem+json"


@pytest.fixture(scope="module")
def template() -> Template:
    return Template.load(Settings().models_dir)


def region_spectrum(template: Template, removed: tuple[str, ...]) -> list[float]:
    """Dirichlet spectrum of the template with some body parts cut away (an independent solve)."""
    keep = ~np.isin(template.labels, [PART_NAMES.index(p) for p in removed])
    faces = template.faces[keep[template.faces].all(axis=1)]
    mesh = Mesh(*drop_unreferenced(template.vertices, faces))
    return list(mesh_spectrum(mesh, SpectrumOptions(k=20)).eigenvalues)


@pytest.fixture(scope="module")
def parts(template):
    upper = region_spectrum(
        template, ("left_thigh", "right_thigh", "left_shin", "right_shin", "left_foot", "right_foot")
    )
    lower = region_spectrum(template, ("head", "neck", "left_upper_arm", "right_upper_arm", "left_hand", "right_hand"))
    no_arm = region_spectrum(template, ("left_upper_arm", "left_forearm", "left_hand"))
    return upper, lower, no_arm


def test_union_is_commutative_monotone_and_inside_its_interval(client, parts):
    upper, lower, _ = parts
    ab = client.post("/v1/union", json={"spectra": [upper, lower]})
    ba = client.post("/v1/union", json={"spectra": [lower, upper]})
    assert ab.status_code == 200, ab.text
    assert ab.json() == ba.json()
    body = ab.json()
    values = np.array(body["eigenvalues"])
    assert len(values) == 20 and body["operands"] == 2
    assert np.all(np.diff(values) >= 0) and np.all(values >= 0)
    assert np.all(np.array(body["lower"]) <= values) and np.all(values <= np.array(body["upper"]))


def test_three_operands_fold_left_to_right(client, parts):
    upper, lower, no_arm = parts
    chained = client.post("/v1/union", json={"spectra": [upper, lower, no_arm]}).json()
    inner = client.post("/v1/union", json={"spectra": [upper, lower]}).json()["eigenvalues"]
    outer = client.post("/v1/union", json={"spectra": [inner, no_arm]}).json()
    np.testing.assert_allclose(chained["eigenvalues"], outer["eigenvalues"], rtol=1e-6)


@pytest.mark.parametrize(
    "spectra, reason",
    [
        ([[1.0] * 20], "one operand"),
        ([[1.0] * 20, [1.0] * 19], "exactly 20"),
        ([[1.0] * 20, [-5.0] + [1.0] * 19], "negative"),
        ([[1.0] * 20, list(range(20, 0, -1))], "ascending"),
        ([[1.0] * 20] * 33, "33 operands"),
    ],
)
def test_bad_spectra_are_422_problems(client, spectra, reason):
    response = client.post("/v1/union", json={"spectra": spectra})
    assert response.status_code == 422, reason
    assert response.headers["content-type"].startswith(PROBLEM)
    assert response.json()["status"] == 422


@pytest.mark.parametrize("literal", ["NaN", "Infinity", "1e400"])
def test_non_finite_values_are_422_problems(client, literal):
    body = '{"spectra": [[' + ",".join(["1.0"] * 19 + [literal]) + "], [" + ",".join(["1.0"] * 20) + "]]}"
    response = client.post("/v1/union", content=body, headers={"content-type": "application/json"})
    assert response.status_code == 422
    assert response.headers["content-type"].startswith(PROBLEM)


def test_localize_reports_vertices_and_part_coverage(client, parts, template):
    response = client.post("/v1/localize", json={"spectrum": parts[2]})
    assert response.status_code == 200, response.text
    body = response.json()
    assert body["template_vertices"] == len(template.vertices)
    vertices = np.array(body["vertices"])
    assert np.all((vertices >= 0) & (vertices < len(template.vertices))) and len(np.unique(vertices)) == len(vertices)
    assert set(body["part_coverage"]) == set(PART_NAMES)
    assert all(0 <= v <= 1 for v in body["part_coverage"].values())
    assert 0 <= body["area_fraction"] <= 1 and not math.isnan(body["area_fraction"])


def test_models_describes_what_is_loaded(client, template):
    body = client.get("/v1/models").json()
    assert body["k"] == 20 and body["template_vertices"] == len(template.vertices)
    assert body["parts"] == list(PART_NAMES)
