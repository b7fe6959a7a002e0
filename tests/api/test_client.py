"""The Python client against the live app (in process, through a TestClient): every endpoint,
its answers checked against the raw HTTP answers and the pipeline, and problems raised whole."""

import numpy as np
import pytest
import trimesh

from app.client import Client, ServiceProblem
from app.core.config import Settings
from app.geometry.pipeline import SpectrumOptions, mesh_spectrum
from app.geometry.shapes import Mesh
from app.inference.template import Template
from app.samples import PARTS, template_part
from harness.builders import mesh_bytes
from tests.api.conftest import API_KEY
from tests.conftest import bumpy_patch, sphere


@pytest.fixture(scope="module")
def service(client):
    return Client(http=client, api_key=API_KEY)


@pytest.fixture(scope="module")
def scans():
    """Two overlapping patches of one surface, as (file name, bytes)."""
    return [(f"patch{seed}.ply", mesh_bytes(bumpy_patch(seed=seed, n=500), "ply")) for seed in (1, 2)]


@pytest.fixture(scope="module")
def scans_apart(scans):
    """The two patches, the second in a frame of its own (a metre off): neither lies on the
    other as sent, and their places (no body part: doubted) join nothing, so their union is the
    learned chain's."""
    patch = bumpy_patch(seed=2, n=500)
    moved = Mesh(patch.vertices + [1.0, 0.0, 0.0], patch.faces)
    return [scans[0], ("patch2.ply", mesh_bytes(moved, "ply"))]


@pytest.fixture(scope="module")
def body_scans():
    """Two parts of the template body (a patch is no body part: its places are doubted, its
    region counts nothing and gets no token), as (file name, bytes)."""
    template = Template.load(Settings().models_dir)
    return [(name, template_part(template, removed)) for name, removed in PARTS.items()]


def test_a_spectrum_is_the_pipelines(service):
    patch = bumpy_patch(seed=1, n=500)
    report = service.spectrum(("patch.ply", mesh_bytes(patch, "ply")), k=12)
    expected = mesh_spectrum(patch, SpectrumOptions(k=12))
    np.testing.assert_allclose(report.eigenvalues, expected.eigenvalues, rtol=1e-6)  # PLY stores float32
    assert report.boundary == "dirichlet" and report.faces_dropped == 0


def test_a_union_of_files_equals_the_union_of_their_spectra_in_either_order(service, scans_apart):
    """Files that do not come together are united told the overlap their places on the template
    measure (none for these bumpy patches, no body part: their places are doubted); their spectra
    told the same, in either order, give the same union."""
    scans = scans_apart
    by_files = service.union(files=scans)
    assert by_files.union_by == "learned-chain"
    spectra = [operand.eigenvalues for operand in by_files.operands]
    told = {"overlap": by_files.overlaps or None, "boundary": by_files.boundaries or None}
    by_spectra = service.union(spectra=spectra[::-1], **told)
    np.testing.assert_allclose(by_spectra.eigenvalues, by_files.eigenvalues, rtol=1e-6)
    mixed = service.union(files=scans[:1], spectra=spectra[1:], **told)
    np.testing.assert_allclose(mixed.eigenvalues, by_files.eigenvalues, rtol=1e-6)
    assert [o.source for o in mixed.operands] == ["files[0] patch1.ply", "spectra[0]"]
    assert np.all(np.asarray(by_files.lower) <= by_files.eigenvalues)


def test_registered_views_sent_one_by_one_are_told_the_overlap_their_uploads_measure(service, scans):
    """The two patches (one surface, one frame) posted with their footprints: the overlap and
    boundary share the tokens measure are the ones the uploads measure together, and a union told
    them by every route is the one measured from the uploads."""
    views = [service.spectrum(scan, footprint=True) for scan in scans]
    assert all(view.footprint.startswith("fp1.") for view in views)
    measured = service.overlap([view.footprint for view in views])
    together = service.union(files=scans, measure_overlap=True)
    assert together.union_by == "fused" and together.overlaps_told == [False]  # fused, told to no operator
    as_sent = service.union(files=scans)  # not said to share a frame: they lie on one another as sent
    assert as_sent.union_by == "aligned"
    assert measured.overlaps == pytest.approx(together.overlaps, abs=0.01)
    assert measured.boundaries == pytest.approx(together.boundaries, abs=0.02)
    spectra = [view.eigenvalues for view in views]
    told = service.union(spectra=spectra, overlap=measured.overlaps, boundary=measured.boundaries)
    assert told.overlaps == pytest.approx(measured.overlaps) and told.boundaries == pytest.approx(measured.boundaries)
    assert told.union_by == "learned-chain" and told.overlaps_told == [True]
    localized = service.localize(spectra=spectra, overlap=measured.overlaps, boundary=measured.boundaries)
    assert localized.eigenvalues == told.eigenvalues


def test_localize_and_retrieve_answer_as_the_raw_endpoints_do(service, scans, client):
    spectra = [o.eigenvalues for o in service.union(files=scans).operands]
    region = service.localize(spectra=spectra)
    raw = client.post("/v1/localize", data={"spectra": str(spectra)}).json()
    assert region.vertices == raw["vertices"] and region.part_coverage == raw["part_coverage"]
    matches = service.retrieve(spectra=spectra, top=3).matches
    raw_matches = client.post("/v1/retrieve", data={"spectra": str(spectra)}, params={"top": 3}).json()["matches"]
    assert [m.id for m in matches] == [m["id"] for m in raw_matches]


def test_a_reconstruction_answers_as_the_raw_endpoint_does(service, client):
    body = sphere(3)
    spectra = [list(mesh_spectrum(body, SpectrumOptions(k=20)).eigenvalues)]
    rebuilt = service.reconstruct(spectra=spectra)
    raw = client.post("/v1/reconstruct", data={"spectra": str(spectra)}).json()
    assert rebuilt.vertices == raw["vertices"] and rebuilt.body_eigenvalues == raw["body_eigenvalues"]
    assert rebuilt.height_m == raw["height_m"] and rebuilt.warnings == raw["warnings"]


def test_a_stored_shape_is_listed_retrieved_first_and_deleted(service):
    ball = trimesh.creation.icosphere(subdivisions=3)
    stored = service.add_shape(("ball.ply", ball.export(file_type="ply")), "ball", units="cm")
    assert stored.label == "ball" and stored.source == "ball.ply"
    best = service.retrieve(spectra=[stored.spectrum], top=1).matches[0]
    assert best.id == stored.id and best.distance == pytest.approx(0.0, abs=1e-9)
    total = service.shapes(limit=1).total
    service.delete_shape(stored.id)
    assert service.shapes(limit=1).total == total - 1
    assert service.models().database.shapes == total - 1


def test_problems_are_raised_with_their_body(service, client):
    with pytest.raises(ServiceProblem) as bad:
        service.union(spectra=[[3.0, 2.0, 1.0]])
    assert bad.value.status == 422 and bad.value.type == "/problems/invalid-spectrum"
    assert "exactly 20 eigenvalues" in bad.value.problem.detail
    with pytest.raises(ServiceProblem) as refused:
        Client(http=client).add_shape(("ball.ply", mesh_bytes(sphere(2), "ply")), "no key")
    assert refused.value.status == 401 and refused.value.type == "/problems/invalid-api-key"
    with pytest.raises(ServiceProblem) as missing:
        service.delete_shape("not-a-shape")
    assert missing.value.status == 404 and missing.value.type == "/problems/shape-not-found"


def test_a_ball_with_a_hole_is_stored_and_retrieved_once_its_hole_is_capped(service):
    """cap_holes through the client: a ball scanned with a 36° polar blind spot is a partial shape
    (refused by the store) until its hole is capped; capped, it is the closed ball again, which
    the store then finds by its own spectrum."""
    ball = trimesh.creation.icosphere(subdivisions=3)
    seen = ball.vertices[:, 2] < 0.8
    holed = trimesh.Trimesh(ball.vertices, ball.faces[seen[ball.faces].all(axis=1)])
    scan = ("holed.ply", holed.export(file_type="ply"))
    assert service.spectrum(scan, k=10).boundary == "dirichlet"
    capped = service.spectrum(scan, k=10, cap_holes=True)
    assert capped.boundary == "none" and capped.holes_filled == 1
    with pytest.raises(ServiceProblem) as partial:
        service.add_shape(scan, "holed ball", units="cm")
    assert partial.value.status == 422 and "cap_holes" in partial.value.problem.detail
    stored = service.add_shape(scan, "holed ball", units="cm", cap_holes=True)
    found = service.retrieve(files=[scan], units="cm", cap_holes=True, top=1)
    assert found.ranked_by == "union" and found.matches[0].id == stored.id
    assert found.matches[0].distance == pytest.approx(0.0, abs=1e-6)
    service.delete_shape(stored.id)


def test_scans_placed_once_are_united_as_spectra_with_their_regions(service, body_scans):
    """The client's correspondence and regions: two scans placed one by one, then sent back as
    spectra with their region tokens, are localized where the uploads are; their union is the
    learned operator's told what the regions say (spectra have no geometry to fuse)."""
    scans = body_scans
    placed = [service.correspondence(scan) for scan in scans]
    assert all(part.vertices == len(part.position) and part.places == "network" for part in placed)
    relaxed = service.correspondence(scans[0], places="relaxed")
    assert relaxed.places == "relaxed" and relaxed.vertex_indices == placed[0].vertex_indices
    spectra, regions = [p.eigenvalues for p in placed], [p.region.token for p in placed]
    by_files = service.localize(files=scans)
    by_spectra = service.localize(spectra=spectra, regions=regions)
    assert by_files.located_by == by_spectra.located_by == "correspondence"
    assert by_spectra.vertices == by_files.vertices
    by_tokens = service.union(spectra=spectra, regions=regions)
    assert by_tokens.union_by == "learned-chain" and by_tokens.overlaps_from == "correspondence"
    np.testing.assert_allclose(by_tokens.eigenvalues, by_spectra.eigenvalues, rtol=1e-6)


def test_a_session_filled_view_by_view_answers_as_the_union_of_its_views(service, scans_apart):
    """The client's sessions: views added one by one to a session answer what one union of
    all of them answers, as the session reads back, until the session is ended."""
    scans = scans_apart
    session = service.new_session()
    assert session.union_by == "empty" and not session.views
    for scan in scans:
        state = service.add_view(session.id, scan)
    assert state.union_by == "learned-chain" and [view.source for view in state.views] == [s[0] for s in scans]
    np.testing.assert_allclose(state.eigenvalues, service.union(files=scans).eigenvalues, rtol=1e-9)
    assert service.session(session.id).eigenvalues == state.eigenvalues
    with pytest.raises(ServiceProblem) as refused:  # two patches of no body do not come together on it
        service.session_body(session.id)
    assert refused.value.status == 409 and refused.value.type == "/problems/body-not-fitted"
    service.end_session(session.id)
    with pytest.raises(ServiceProblem) as raised:
        service.session(session.id)
    assert raised.value.status == 404 and raised.value.type == "/problems/session-not-found"
