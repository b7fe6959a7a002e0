"""Per-part coverage on the served template: the shares a front-end's "still missing" list reads."""

from pathlib import Path

import numpy as np

from app.geometry.laplacian import mesh_operators
from app.inference.template import PART_NAMES, Template, part_coverage

MODELS = Path(__file__).resolve().parents[2] / "models"


def test_part_coverage_of_whole_parts_and_halves():
    template = Template.load(MODELS)
    area = mesh_operators(template.vertices, template.faces).mass.diagonal()
    hand = template.labels == PART_NAMES.index("left_hand")
    masks = np.stack([np.ones_like(hand), ~hand, hand])
    coverage = part_coverage(masks, area, template.labels)
    left_hand = PART_NAMES.index("left_hand")
    np.testing.assert_allclose(coverage[0], 1.0)
    np.testing.assert_allclose(np.delete(coverage[1], left_hand), 1.0)
    assert coverage[1, left_hand] == 0 and coverage[2, left_hand] == 1
    assert np.delete(coverage[2], left_hand).max() == 0
    # Half the torso's area (its vertices in order until their areas sum to half) covers half of it.
    torso = np.flatnonzero(template.labels == PART_NAMES.index("torso"))
    half = torso[: np.searchsorted(np.cumsum(area[torso]), area[torso].sum() / 2) + 1]
    mask = np.zeros(len(area), dtype=bool)
    mask[half] = True
    share = part_coverage(mask, area, template.labels)[PART_NAMES.index("torso")]
    assert abs(share - 0.5) <= area[torso].max() / area[torso].sum()
