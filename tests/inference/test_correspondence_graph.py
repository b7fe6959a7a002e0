"""The served correspondence graph: any part size, basis size and stencil width; places that
come back finite, within the template, and for a part cut from the template, near themselves,
whether read whole or through its simplified copy."""

from pathlib import Path

import numpy as np
import pytest

from app.contract import CORRESPONDENCE_FILE
from app.geometry.descriptors import cloud_inputs, mesh_inputs
from app.geometry.laplacian import mesh_operators
from app.geometry.placing import Part, mesh_part
from app.geometry.topology import drop_unreferenced
from app.inference.correspondence import Placement
from app.inference.models import SpectralModels
from app.inference.template import PART_NAMES, faces_inside
from app.samples import PARTS, template_part_mesh
from tests.conftest import sphere

MODELS = Path(__file__).resolve().parents[2] / "models"
pytestmark = pytest.mark.skipif(not (MODELS / CORRESPONDENCE_FILE).exists(), reason="no correspondence graph")


@pytest.fixture(scope="module")
def models() -> SpectralModels:
    return SpectralModels(MODELS)


def _template_part(models: SpectralModels, kept: list[str]) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The template's faces inside the given body parts: (vertices, faces, each vertex's template index)."""
    template = models.template
    mask = np.isin(template.labels, [PART_NAMES.index(name) for name in kept])
    faces = template.faces[faces_inside(mask, template.faces)]
    used = np.zeros(len(mask), bool)
    used[faces.ravel()] = True
    vertices, faces = drop_unreferenced(template.vertices, faces)
    return vertices, faces, np.flatnonzero(used)


@pytest.mark.parametrize("subdivisions", [1, 3])
def test_small_parts_and_short_bases_are_placed(models, subdivisions):
    """A 42-vertex sphere has a basis of 41 and a stencil 5–6 wide: the graph takes both."""
    mesh = sphere(subdivisions)
    inputs = mesh_inputs(0.1 * mesh.vertices, mesh.faces)
    placement = models.correspondence.place(Part.itself(inputs))
    assert placement.position.shape == (len(mesh.vertices), 3)
    assert np.isfinite(placement.position).all() and ((0 <= placement.confidence) & (placement.confidence <= 1)).all()
    low, high = models.template.vertices.min(axis=0), models.template.vertices.max(axis=0)
    assert np.all((placement.position >= low - 0.1) & (placement.position <= high + 0.1))


def test_a_template_part_lands_near_itself_mesh_or_cloud(models):
    """The torso, hips and thighs cut from the template: most of their vertices land within 10 cm of
    themselves, as a mesh and as a point cloud, and the region holds the torso, not the head."""
    vertices, faces, index = _template_part(models, ["torso", "hips", "left_thigh", "right_thigh"])
    truth = models.template.vertices[index]
    for inputs in (mesh_inputs(vertices, faces), cloud_inputs(vertices, None)):
        placement = models.correspondence.place(Part.itself(inputs))
        assert np.mean(np.linalg.norm(placement.position - truth, axis=1) < 0.10) > 0.8
    cover = models.correspondence.cover(models.correspondence.place(Part.itself(mesh_inputs(vertices, faces))))
    region = models.region_of(cover.region, cover.share)
    assert region.part_coverage["torso"] > 0.7 and region.part_coverage["head"] < 0.2


def test_a_part_of_a_smaller_body_is_placed_where_it_lies(models, monkeypatch):
    """The torso, hips and thighs cut from the template and shrunk to a child's size (0.65: the
    network learnt adults only): read as sent, their places fall elsewhere; read at the
    magnification the graph is surest at, they land as the adult-sized part does (most within
    10 cm of themselves), the graph says how much it magnified, and an adult-sized part is read
    as sent."""
    vertices, faces, index = _template_part(models, ["torso", "hips", "left_thigh", "right_thigh"])
    truth = models.template.vertices[index]
    graph = models.correspondence.graph
    adult = graph.run(Part.itself(mesh_inputs(vertices, faces)))
    child = graph.run(Part.itself(mesh_inputs(0.65 * vertices, faces)))
    assert adult.magnification == 1.0
    assert 1.3 < child.magnification < 1.8
    near = [np.mean(np.linalg.norm(places.position - truth, axis=1) < 0.10) for places in (adult, child)]
    assert near[1] > 0.8 and near[1] > near[0] - 0.1
    monkeypatch.setattr("app.inference.correspondence.MAGNIFICATION_STEPS", (0, 0))
    as_sent = graph.run(Part.itself(mesh_inputs(0.65 * vertices, faces)))
    assert as_sent.magnification == 1.0
    assert np.mean(np.linalg.norm(as_sent.position - truth, axis=1) < 0.10) < near[1] - 0.2


def test_a_part_is_crowded_against_the_area_it_was_read_at(models):
    """The template's torso placed exactly on itself, each vertex with its own area: its region
    keeps its area, so it is not crowded as read (× 1); the same places from a part read at × 2
    (its area, as read, four times the region's) are crowded, as a ball's are."""
    correspondence = models.correspondence
    vertices, _, index = _template_part(models, ["torso"])
    area = models.vertex_area[index]
    as_read = [
        Placement(vertices, np.ones(len(index)), index, area, np.zeros(len(index), bool), magnification)
        for magnification in (1.0, 2.0)
    ]
    crowded = [any("crowd" in doubt for doubt in correspondence.doubts(p, correspondence.cover(p))) for p in as_read]
    assert crowded == [False, True]


def test_a_graph_trained_on_other_features_is_refused(monkeypatch):
    """The engine computing one feature more than the graph was trained on (a model file older
    than the code): the graph is refused at load, not fed columns it would misread."""
    import app.inference.correspondence as correspondence

    correspondence.PlacingGraph(MODELS / CORRESPONDENCE_FILE)
    monkeypatch.setattr(correspondence, "FEATURES", correspondence.FEATURES + 1)
    with pytest.raises(ValueError, match="features"):
        correspondence.PlacingGraph(MODELS / CORRESPONDENCE_FILE)


def test_a_part_placed_through_its_copy_lands_where_it_lands_itself(models):
    """The README's 10 k-vertex sample (the template less a forearm and hand: each vertex's true
    place is itself) through its copy of ~6 000 vertices, as served, and on its own vertices:
    the copy's places err at most half a centimetre more, and the two regions agree to 98 %."""
    part = template_part_mesh(models.template, PARTS["no_left_forearm_hand.ply"])
    operators = mesh_operators(part.vertices, part.faces)
    copied = mesh_part(part.vertices, part.faces, operators)
    itself = Part.itself(mesh_inputs(part.vertices, part.faces, operators=operators))
    assert copied.source is not None and copied.inputs.vertices < 0.7 * len(part.vertices)
    through, own = (models.correspondence.placed(p) for p in (copied, itself))
    weight = own.placement.area / own.placement.area.sum()
    error = [np.linalg.norm(p.placement.position - part.vertices, axis=1) @ weight for p in (through, own)]
    assert error[1] < 0.03 and error[0] < error[1] + 0.005
    area = models.vertex_area
    assert area[through.region & own.region].sum() / area[through.region | own.region].sum() > 0.98
