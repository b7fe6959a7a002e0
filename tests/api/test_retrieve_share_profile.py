"""``/v1/retrieve`` with two operands whose overlap is not told: ranked by the share profile.

The independent truth: the unions the service answers on ``/v1/union`` told each share of the
profile, and the ShapeDNA distance written out here (Euclidean on log λ₂…λ_k) from each of them
to every stored shape listed by ``/v1/shapes``; each shape's profiled distance is its smallest.
The operands: the template body cut at mid-height into two parts that share a band, so their
union is the closed template body.
"""

import json

import numpy as np
import pytest

from app.contract import PROFILE_SHARES
from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from app.geometry.topology import drop_unreferenced
from app.inference.template import Template

TOP = 8


@pytest.fixture(scope="module")
def halves() -> list[list[float]]:
    """Spectra of the template body above and below its mid-height, sharing a 10 cm band."""
    template = Template.load(Settings().models_dir)
    height = template.vertices[:, 2]
    middle = (height.min() + height.max()) / 2
    parts = []
    for keep in (height > middle - 0.05, height < middle + 0.05):
        faces = template.faces[keep[template.faces].all(axis=1)]
        part = Mesh(*drop_unreferenced(template.vertices, faces))
        parts.append(list(mesh_spectrum(part, SpectrumOptions()).eigenvalues))
    return parts


def stored_shapes(client) -> tuple[list[str], np.ndarray]:
    labels, spectra, offset = [], [], 0
    while True:
        page = client.get("/v1/shapes", params={"offset": offset, "limit": 500}).json()
        labels += [shape["label"] for shape in page["shapes"]]
        spectra += [shape["spectrum"] for shape in page["shapes"]]
        offset += len(page["shapes"])
        if offset >= page["total"]:
            return labels, np.array(spectra)


def shapedna(query: np.ndarray, stored: np.ndarray) -> np.ndarray:
    return np.sqrt(((np.log(stored[:, 1:]) - np.log(query[1:])) ** 2).sum(axis=1))


def retrieve(client, spectra: list[list[float]], **params) -> dict:
    response = client.post("/v1/retrieve", params={"top": TOP, **params}, data={"spectra": json.dumps(spectra)})
    assert response.status_code == 200, response.text
    return response.json()


def test_two_untold_operands_are_ranked_by_the_share_that_explains_each_stored_shape(client, halves):
    labels, stored = stored_shapes(client)
    told = []
    for share in PROFILE_SHARES:
        response = client.post("/v1/union", params={"overlap": f"{share:.6f}"}, data={"spectra": json.dumps(halves)})
        assert response.status_code == 200, response.text
        told.append(np.array(response.json()["eigenvalues"]))
    each = np.stack([shapedna(union, stored) for union in told])
    expected = np.argsort(each.min(axis=0), kind="stable")[:TOP]

    answer = retrieve(client, halves)
    assert answer["ranked_by"] == "share_profile"
    assert [m["label"] for m in answer["matches"]] == [labels[i] for i in expected]
    np.testing.assert_allclose([m["distance"] for m in answer["matches"]], each.min(axis=0)[expected], rtol=1e-4)
    np.testing.assert_allclose([m["share"] for m in answer["matches"]], PROFILE_SHARES[each.argmin(axis=0)[expected]])
    first_share = PROFILE_SHARES.tolist().index(answer["matches"][0]["share"])
    np.testing.assert_allclose(answer["looked_up"], told[first_share], rtol=1e-6)
    untold = client.post("/v1/union", data={"spectra": json.dumps(halves)}).json()["eigenvalues"]
    np.testing.assert_allclose(answer["query"], untold, rtol=1e-9)


@pytest.mark.parametrize(
    "params, operands",
    [({"overlap": "0.4"}, 2), ({"profile": "false"}, 2), ({}, 3)],
    ids=["overlap told", "profile=false", "three operands"],
)
def test_a_told_overlap_no_profile_or_a_chain_ranks_the_union_itself(client, halves, params, operands):
    spectra = (halves * 2)[:operands]
    answer = retrieve(client, spectra, **params)
    assert answer["ranked_by"] == "union"
    assert all(m["share"] is None for m in answer["matches"])
    labels, stored = stored_shapes(client)
    distance = shapedna(np.array(answer["query"]), stored)
    assert [m["label"] for m in answer["matches"]] == [labels[i] for i in np.argsort(distance, kind="stable")[:TOP]]
