"""Placing that knows when it does not know: a shape that is no body part (a torus, a capsule, a
ball) is answered with a warning and covers nothing, takes no part in a localization, and a
union names each upload whose places are uncertain; the template's own parts are placed
without a warning."""

import numpy as np
import pytest
import trimesh

from harness.builders import ascii_ply
from tests.api.conftest import correspond

pytestmark = pytest.mark.filterwarnings("ignore::DeprecationWarning")


def _ply(mesh: trimesh.Trimesh) -> bytes:
    return ascii_ply(np.asarray(mesh.vertices), np.asarray(mesh.faces))


# Shapes no human scan is part of (sizes of a body's): the graph places them far less certainly
# than the least certain held-out body parts, or crowds their places onto a spot (a closed 10 cm
# ball is placed with confidence 0.84, on 9 % of its area).
NOT_BODY_PARTS = {
    "torus.ply": trimesh.creation.torus(0.2, 0.05, major_sections=64, minor_sections=32),
    "capsule.ply": trimesh.creation.capsule(0.4, 0.05, count=[32, 32]),
    "ball.ply": trimesh.creation.icosphere(4, 0.3),
    "small-ball.ply": trimesh.creation.icosphere(4, 0.1),
}


@pytest.mark.parametrize("name", sorted(NOT_BODY_PARTS))
def test_a_shape_that_is_no_body_part_is_warned_and_covers_nothing(client, name):
    """A torus, a capsule or a ball is still answered (a statue is not refused), warned that its
    places cannot be trusted, its region empty, no body part covered, and no token: a token would
    carry a made-up region into later unions."""
    answer = correspond(client, name, _ply(NOT_BODY_PARTS[name])).json()
    assert any("not part of a human body" in warning for warning in answer["warnings"])
    assert any("left out of coverage" in warning for warning in answer["warnings"])
    region = answer["region"]
    assert region["vertices"] == [] and region["area_fraction"] == 0.0 and region["token"] is None
    assert set(region["part_coverage"].values()) == {0.0}
    assert answer["placed_on"] == answer["vertices"]  # small enough to be read itself


def test_a_shape_that_is_no_body_part_takes_no_part_in_a_localization(client, samples):
    """A body part and a ball localized together: the region is the body part's alone, and the
    step that adds the ball is not told an overlap measured with a region nobody knows."""
    name, data = next(iter(samples.items()))
    files = [("files", (name, data)), ("files", ("small-ball.ply", _ply(NOT_BODY_PARTS["small-ball.ply"])))]
    both = client.post("/v1/localize", files=files).json()
    alone = correspond(client, name, data).json()["region"]
    assert both["located_by"] == "correspondence"
    assert set(both["vertices"]) == set(alone["vertices"])
    assert both["part_coverage"] == pytest.approx(alone["part_coverage"])
    union = client.post("/v1/union", files=files).json()
    assert union["overlaps_told"] == [False]
    assert any(w.startswith("files[1] small-ball.ply") and "not part of a human body" in w for w in union["warnings"])


def test_parts_of_the_template_body_are_placed_without_a_warning(client, samples):
    below = client.app.state.resources.require_models().correspondence.uncertain_below
    for sample, data in samples.items():
        placed = correspond(client, sample, data).json()
        assert placed["mean_confidence"] >= below and placed["warnings"] == []


@pytest.mark.parametrize("uncertain_below", [0.0, 1.01])
def test_a_union_names_the_upload_whose_places_are_uncertain(client, samples, uncertain_below):
    """Below the graph's threshold the union's warnings name each upload whose places are
    uncertain (every place is, below 1.01), and at 0 none."""
    correspondence = client.app.state.resources.require_models().correspondence
    kept, correspondence.uncertain_below = correspondence.uncertain_below, uncertain_below
    try:
        files = [("files", (name, data)) for name, data in samples.items()]
        warnings = client.post("/v1/union", files=files).json()["warnings"]
    finally:
        correspondence.uncertain_below = kept
    doubted = [w.split(":")[0] for w in warnings if "its places on the template are uncertain" in w]
    assert doubted == ([f"files[{i}] {name}" for i, name in enumerate(samples)] if uncertain_below > 1 else [])
