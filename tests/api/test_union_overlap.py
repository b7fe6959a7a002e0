"""Unions told how much their operands overlap (``overlap``, one share per union step) and how much of
their boundary is left on the union's (``boundary``, beside it)."""

import json

import fast_simplification
import numpy as np
import pytest
from prometheus_client import REGISTRY

from app.contract import UNKNOWN_BOUNDARY, UNKNOWN_OVERLAP
from app.geometry.overlap import WIRE_POINTS, footprint_of, footprint_token
from app.geometry.shapes import Mesh
from app.inference.models import InvalidOverlap, checked_boundaries, checked_overlaps
from app.inference.template import PART_NAMES
from app.samples import PARTS as SAMPLE_PARTS
from app.samples import sample_overlap, template_part
from tests.api.test_union_api import LEGS, PROBLEM, ply_bytes, region, spectrum

LEFT_ARM = ("left_upper_arm", "left_forearm", "left_hand")


@pytest.fixture(scope="module")
def nested(template):  # noqa: F811 (the fixture)
    """The body without its legs, and a part of it: that without its left arm too (all inside)."""
    return spectrum(region(template, LEGS)), spectrum(region(template, LEGS + LEFT_ARM))


def union(client, spectra, overlaps=None, boundaries=None):
    params = {}
    if overlaps is not None:
        params["overlap"] = ",".join(map(str, overlaps))
    if boundaries is not None:
        params["boundary"] = ",".join(map(str, boundaries))
    return client.post("/v1/union", data={"spectra": json.dumps(spectra)}, params=params or None)


def test_overlaps_are_one_share_per_step_or_unknown_for_every_step():
    assert checked_overlaps(None, 3, readable=True) == [UNKNOWN_OVERLAP, UNKNOWN_OVERLAP]
    assert checked_overlaps(None, 1, readable=False) == []
    assert checked_overlaps([0.0, 1.0], 3, readable=True) == [0.0, 1.0]
    for overlaps, operands, readable in (
        ([0.5], 2, False),  # a graph without the input cannot be told
        ([0.5, 0.5], 2, True),
        ([], 2, True),
        ([float("nan")], 2, True),
        ([-0.1], 2, True),
        ([1.5], 2, True),
    ):
        with pytest.raises(InvalidOverlap):
            checked_overlaps(overlaps, operands, readable)


def test_boundary_shares_are_one_per_step_beside_the_overlaps_or_unknown_for_every_step():
    assert checked_boundaries(None, None, 3, readable=True) == [UNKNOWN_BOUNDARY, UNKNOWN_BOUNDARY]
    assert checked_boundaries(None, [0.5], 2, readable=False) == [UNKNOWN_BOUNDARY]
    assert checked_boundaries([0.0, 1.0], [0.5, 0.5], 3, readable=True) == [0.0, 1.0]
    for boundaries, overlaps, operands, readable in (
        ([0.5], None, 2, True),  # read beside a told overlap only
        ([0.5], [0.5], 2, False),  # a graph without the input cannot be told
        ([0.5, 0.5], [0.5], 2, True),
        ([float("nan")], [0.5], 2, True),
        ([-0.1], [0.5], 2, True),
        ([1.5], [0.5], 2, True),
    ):
        with pytest.raises(InvalidOverlap):
            checked_boundaries(boundaries, overlaps, operands, readable)


def test_the_served_operator_reads_the_overlap_and_the_boundary_share(client):
    models = client.app.state.resources.require_models()
    assert models.reads_overlap and models.reads_boundary
    route = client.get("/openapi.json").json()["paths"]["/v1/union"]["post"]
    assert {"overlap", "boundary", "measure_overlap"} <= {parameter["name"] for parameter in route["parameters"]}
    assert client.get("/v1/models").json()["told"] == ["overlap", "boundary"]


@pytest.mark.parametrize(
    ("params", "named"),
    [
        ({"overlap": "0.5", "boundary": "0.5,0.5"}, "boundary"),
        ({"overlap": "0.5", "boundary": "nan"}, "boundary"),
        ({"overlap": "0.5", "boundary": "1.5"}, "boundary"),
        ({"overlap": "0.5", "boundary": "open"}, "boundary"),
        ({"boundary": "0.5"}, "beside overlap"),
    ],
)
def test_a_wrong_boundary_share_is_a_422_problem_naming_it(client, nested, params, named):
    response = client.post("/v1/union", data={"spectra": json.dumps(list(nested))}, params=params)
    assert response.status_code == 422, response.text
    assert response.json()["type"] == "/problems/invalid-overlap" and named in response.json()["detail"]


@pytest.mark.parametrize("share", [0.0, 0.4, 1.0])
@pytest.mark.parametrize("boundary", [0.0, 0.6, 1.0])
def test_a_union_told_its_boundary_share_keeps_the_laws(client, nested, share, boundary):
    """Told any overlap and boundary share: commutative, never above either part, and one spectrum
    twice is itself; told it, the answer is another one than told the overlap alone."""
    larger, smaller = nested
    ab = union(client, [larger, smaller], [share], [boundary]).json()
    ba = union(client, [smaller, larger], [share], [boundary]).json()
    assert ab["eigenvalues"] == ba["eigenvalues"] and ab["sigma"] == ba["sigma"]
    assert ab["boundaries"] == [boundary] and ab["overlaps"] == [share]
    assert np.all(np.array(ab["eigenvalues"]) <= np.minimum(larger, smaller) * (1 + 1e-6))
    itself = union(client, [smaller, smaller], [share], [boundary]).json()
    np.testing.assert_allclose(itself["eigenvalues"], smaller, rtol=1e-5)
    assert ab["eigenvalues"] != union(client, [larger, smaller], [share]).json()["eigenvalues"]


@pytest.mark.parametrize("overlap", ["0.5,0.5", "nan", "-0.2", "2", "half", "", "0.5,"])
def test_a_wrong_overlap_is_a_422_problem_naming_it(client, nested, overlap):
    response = client.post("/v1/union", data={"spectra": json.dumps(list(nested))}, params={"overlap": overlap})
    assert response.status_code == 422, response.text
    assert response.headers["content-type"] == PROBLEM
    assert response.json()["type"] == "/problems/invalid-overlap"
    assert "overlap" in response.json()["detail"]


def test_an_overlap_given_twice_is_refused_like_any_repeated_parameter(client, nested):
    response = client.post("/v1/union?overlap=0.5&overlap=0.5", data={"spectra": json.dumps(list(nested))})
    assert response.status_code == 422 and response.json()["type"] == "/problems/invalid-request"


def test_an_overlap_count_that_does_not_fit_costs_no_solve(client, nested, template):  # noqa: F811
    """The count is checked before the uploads are solved: no solve is recorded for the request."""
    upload = ply_bytes(region(template, LEGS))
    files = [("files", ("a.ply", upload)), ("files", ("b.ply", upload))]
    before = _solves()
    response = client.post("/v1/union", params={"overlap": "0.5,0.5"}, files=files)
    assert response.status_code == 422 and response.json()["type"] == "/problems/invalid-overlap"
    assert _solves() == before
    assert client.post("/v1/union", params={"overlap": "0.5"}, files=files).status_code == 200
    assert _solves() == before + 2  # the count would have seen solves


@pytest.mark.parametrize(
    ("route", "params"),
    [
        ("/v1/retrieve", {"top": 0}),
        ("/v1/localize", {"format": "xml"}),
        ("/v1/reconstruct", {"format": "xml"}),
        ("/v1/union", {"measure_overlap": "maybe"}),
    ],
)
def test_a_malformed_route_parameter_costs_no_solve(client, template, route, params):  # noqa: F811
    """Every union route takes its union as one dependency that solves only when the route asks,
    after FastAPI has checked the route's own parameters: a malformed one is a 422 with the
    uploads never solved."""
    upload = ply_bytes(region(template, LEGS))
    before = _solves()
    response = client.post(route, params=params, files=[("files", ("a.ply", upload)), ("files", ("b.ply", upload))])
    assert response.status_code == 422, response.text
    assert response.headers["content-type"] == PROBLEM
    assert _solves() == before


def _solves() -> float:
    """Solves the service has recorded (its Prometheus histogram's count)."""
    return REGISTRY.get_sample_value("spectral_unions_solve_seconds_count") or 0.0


@pytest.mark.parametrize("share", [0.0, 0.4, 1.0])
def test_a_told_union_keeps_the_laws(client, nested, share):
    """Told any overlap: commutative, never above either part, and one spectrum twice is itself."""
    larger, smaller = nested
    ab, ba = union(client, [larger, smaller], [share]).json(), union(client, [smaller, larger], [share]).json()
    assert ab["eigenvalues"] == ba["eigenvalues"] and ab["sigma"] == ba["sigma"]
    assert np.all(np.array(ab["eigenvalues"]) <= np.minimum(larger, smaller) * (1 + 1e-6))
    itself = union(client, [smaller, smaller], [share]).json()
    np.testing.assert_allclose(itself["eigenvalues"], smaller, rtol=1e-5)


def test_a_chain_is_told_one_overlap_per_step(client, nested, template):  # noqa: F811
    larger, smaller = nested
    third = spectrum(region(template, ("head", "neck")))
    chained = union(client, [larger, smaller, third], [1.0, 0.6]).json()
    inner = union(client, [larger, smaller], [1.0]).json()["eigenvalues"]
    outer = union(client, [inner, third], [0.6]).json()
    np.testing.assert_allclose(chained["eigenvalues"], outer["eigenvalues"], rtol=1e-6)


@pytest.mark.parametrize(
    "removed",
    [(LEGS, LEGS + LEFT_ARM), (("head", "neck"), ("head", "neck") + LEFT_ARM)],
    ids=["no legs, then no left arm too", "no head, then no left arm too"],
)
def test_told_that_one_part_is_inside_the_other_the_union_is_the_larger_part(client, template, removed):  # noqa: F811
    """Absorption, U(A, B) = B for A ⊂ B, told overlap 1: the served operator's union is within 3 %
    of the larger part (mean over λ₂…λ₂₀; measured 0.8 and 2.0 %), four times closer than untold
    (measured 11.6 and 16.1 %: the spectra alone do not say the parts are nested)."""
    larger, smaller = (spectrum(region(template, parts)) for parts in removed)
    told = np.array(union(client, [larger, smaller], [1.0]).json()["eigenvalues"])
    untold = np.array(union(client, [larger, smaller]).json()["eigenvalues"])

    def error(values: np.ndarray) -> float:
        return float((np.abs(values - larger) / np.array(larger))[1:].mean())

    assert error(told) <= 0.03 and error(told) * 4 <= error(untold)


def test_uploads_in_one_frame_have_their_overlap_measured(client, chain_client, template):  # noqa: F811
    """The README's two sample parts (the template less head and neck, less left forearm and hand):
    the measured share is their true one from the template's faces; the uploads are fused, told
    to no operator, and their union is the closed body, glued back from the parts' own triangles
    (its spectrum the body's own); without the sessions' calibration the fold is the one told
    that share."""
    files = [("files", (name, template_part(template, removed))) for name, removed in SAMPLE_PARTS.items()]
    measured = client.post("/v1/union", params={"measure_overlap": "true"}, files=files)
    assert measured.status_code == 200, measured.text
    (share,) = measured.json()["overlaps"]
    assert share == pytest.approx(sample_overlap(template), abs=0.02)
    (boundary,) = measured.json()["boundaries"]
    assert boundary <= 0.02  # their union is the closed body: each part's edge lies inside the other
    assert measured.json()["union_by"] == "fused" and measured.json()["overlaps_told"] == [False]
    body = np.array(spectrum(region(template, ())))

    def error(values: list[float]) -> float:  # λ₁ of the closed body is 0
        return float((np.abs(np.array(values) - body) / body)[1:].mean())

    spectra = [operand["eigenvalues"] for operand in measured.json()["operands"]]
    told = union(client, spectra, [share], [boundary]).json()
    folded = chain_client.post("/v1/union", params={"measure_overlap": "true"}, files=files).json()
    assert error(measured.json()["eigenvalues"]) < 1e-5 < error(folded["eigenvalues"])
    assert folded["union_by"] == "learned-chain" and folded["overlaps"] == pytest.approx([share])
    np.testing.assert_allclose(folded["eigenvalues"], told["eigenvalues"], rtol=1e-5)
    assert told["overlaps"] == pytest.approx([share]) and told["boundaries"] == pytest.approx([boundary])
    assert union(client, spectra).json()["overlaps"] == [] and union(client, spectra).json()["boundaries"] == []


@pytest.mark.parametrize("measure", ["true", "false"], ids=["one frame", "aligned"])
def test_a_part_with_its_remeshed_copy_is_the_part(client, template, measure):  # noqa: F811
    """A part sent with a copy of it re-meshed (30 % of its vertices collapsed, none where they
    were): each lies whole on the other, so their union is the part, U(A, A') = A; answered as
    the part's own spectrum, not a point cloud of the two (5 to 8 % off before)."""
    part = region(template, ("head", "neck"))
    points, triangles = fast_simplification.simplify(part.vertices, part.faces, target_reduction=0.3)
    copy = Mesh(np.asarray(points, np.float64), np.asarray(triangles, np.int64))
    files = [("files", ("part.ply", ply_bytes(part))), ("files", ("copy.ply", ply_bytes(copy)))]
    answer = client.post("/v1/union", params={"measure_overlap": measure}, files=files)
    assert answer.status_code == 200, answer.text
    assert answer.json()["union_by"] == ("fused" if measure == "true" else "aligned")
    np.testing.assert_allclose(answer.json()["eigenvalues"], spectrum(part), rtol=1e-6)


def test_a_part_inside_another_is_measured_whole(client, template):  # noqa: F811
    parts = (LEGS, LEGS + LEFT_ARM)
    files = [("files", (f"{i}.ply", ply_bytes(region(template, removed)))) for i, removed in enumerate(parts)]
    response = client.post("/v1/union", params={"measure_overlap": "true"}, files=files)
    assert response.json()["overlaps"] == pytest.approx([1.0], abs=0.01)


@pytest.mark.parametrize(
    "extra",
    [{"overlap": "0.5"}, {"boundary": "0.5"}, {"spectra": "[[1,2,3]]"}],
    ids=["told too", "boundary told too", "a spectrum"],
)
def test_a_measured_overlap_needs_uploads_alone_and_is_refused_before_solving(client, template, extra):  # noqa: F811
    upload = ply_bytes(region(template, LEGS))
    files = [("files", ("a.ply", upload)), ("files", ("b.ply", upload))]
    params = {"measure_overlap": "true", **{k: v for k, v in extra.items() if k != "spectra"}}
    data = {k: v for k, v in extra.items() if k == "spectra"}
    before = _solves()
    response = client.post("/v1/union", params=params, data=data, files=files)
    assert response.status_code == 422 and response.json()["type"] == "/problems/invalid-overlap"
    assert _solves() == before


def footprinted(client, name: str, upload: bytes) -> dict:
    """A view posted as a scanning front-end posts it: its spectrum and footprint token."""
    response = client.post("/v1/spectrum", params={"footprint": "true"}, files={"file": (name, upload)})
    assert response.status_code == 200, response.text
    return response.json()


def measured(client, tokens: list[str]):
    """POST /v1/overlap as a browser's FormData sends it: multipart."""
    return client.post("/v1/overlap", files={"footprints": (None, json.dumps(tokens))})


def test_views_sent_one_by_one_have_the_overlap_the_uploads_together_have(
    client,
    chain_client,
    template,  # noqa: F811
):
    """The README's two sample parts posted one at a time: their tokens (each part thinned from
    ~10 000 vertices to 4 096 points) measure about the share that measure_overlap measures on
    the two uploads and the template's faces give, and a boundary share of about 0 (their union
    is the closed body: each part's edge lies inside the other). Told both, the learned union is
    as close to the truth, the whole body, as the fold measured from the uploads, and closer than
    told the share alone (two parts whose union closes the surface are what the boundary share
    tells); the uploads fused are closer than either."""
    uploads = [(name, template_part(template, removed)) for name, removed in SAMPLE_PARTS.items()]
    views = [footprinted(client, name, upload) for name, upload in uploads]
    answer = measured(client, [v["footprint"] for v in views])
    assert answer.status_code == 200, answer.text
    (share,), (boundary,) = answer.json()["overlaps"], answer.json()["boundaries"]
    files = [("files", u) for u in uploads]
    together = chain_client.post("/v1/union", params={"measure_overlap": "true"}, files=files)
    assert share == pytest.approx(together.json()["overlaps"][0], abs=0.03)
    assert share == pytest.approx(sample_overlap(template), abs=0.03)
    assert boundary == pytest.approx(together.json()["boundaries"][0], abs=0.02) and boundary <= 0.02
    body = np.array(spectrum(region(template, ())))
    spectra = [v["eigenvalues"] for v in views]

    def error(values: list[float]) -> float:
        return float((np.abs(np.array(values) - body) / body)[1:].mean())

    both = error(union(client, spectra, [share], [boundary]).json()["eigenvalues"])
    assert both <= error(together.json()["eigenvalues"]) + 0.01
    assert both < error(union(client, spectra, [share]).json()["eigenvalues"])
    fused = client.post("/v1/union", params={"measure_overlap": "true"}, files=files).json()
    assert fused["union_by"] == "fused" and error(fused["eigenvalues"]) < both


def test_a_session_measured_view_by_view_through_the_union_token_is_the_fold(client, template):  # noqa: F811
    """Three views — the body less its legs, less its left arm too (inside the first), the legs
    alone (outside both) — sent as [union so far, next] each step: the shares are those of all
    three at once, and the legs touch the union so far only along the cut."""
    parts = (LEGS, LEGS + LEFT_ARM, tuple(p for p in PART_NAMES if p not in LEGS))
    tokens = [footprinted(client, f"{i}.ply", ply_bytes(region(template, p)))["footprint"] for i, p in enumerate(parts)]
    first = measured(client, tokens[:2]).json()
    second = measured(client, [first["union_footprint"], tokens[2]]).json()
    at_once = measured(client, tokens).json()["overlaps"]
    assert first["overlaps"] == pytest.approx([1.0], abs=0.025)  # inside the first: 0.984 measured from tokens
    assert [*first["overlaps"], *second["overlaps"]] == pytest.approx(at_once, abs=0.02)
    assert at_once[1] < 0.1


@pytest.mark.parametrize(
    ("field", "reason"),
    [
        ("[]", "non-empty JSON list"),
        ('"fp1.AAAA"', "non-empty JSON list"),
        ("[1, 2]", "non-empty JSON list"),
        ("[fp1", "not valid JSON"),
        ('["fp1.AAAAAAAAAAAAAAAAAAAAAA==", "x"]', "footprints[0] does not hold whole"),
        (json.dumps(["fp1.AAAA"] * 33), "at most 32"),
    ],
)
def test_a_wrong_footprint_is_a_422_problem_naming_it(client, field, reason):
    response = client.post("/v1/overlap", data={"footprints": field})
    assert response.status_code == 422, response.text
    assert response.headers["content-type"] == PROBLEM
    assert response.json()["type"] == "/problems/invalid-overlap"
    assert reason in response.json()["detail"]


def test_a_footprint_is_not_asked_with_eigenfunctions(client, template):  # noqa: F811
    upload = ply_bytes(region(template, LEGS))
    response = client.post(
        "/v1/spectrum", params={"footprint": "true", "vectors": "true"}, files={"file": ("a.ply", upload)}
    )
    assert response.status_code == 422 and response.json()["type"] == "/problems/invalid-request"


def test_seven_full_tokens_fit_a_form_field_and_eight_are_a_400(client):
    """A full token is 131 076 characters: seven fit the 1 MiB form-field cap, eight do not (a
    client sends the union's token and the new view's, two)."""
    points = np.random.default_rng(0).random((WIRE_POINTS + 10, 3))
    token = footprint_token(footprint_of(points, np.full(len(points), 1e-4)))
    assert len(token) == 131_076 and measured(client, [token] * 7).status_code == 200
    response = measured(client, [token] * 8)
    assert response.status_code == 400 and response.json()["type"] == "/problems/invalid-form"
