"""What a placed part covers (:mod:`app.inference.cover`): its covered share, and the token a
client keeps it by.

The truths: a region placed exactly, vertex on vertex, is covered in full inside and not at all
far from it, and its shares sum to its own area (its coverage is its own, to a few per cent); a token gives back
the cover it was made of (the share to its sixteenths); tokens of the region-only format still
read as the region, fully covered; a token of another template, or of nothing, is refused.
"""

import base64
from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from app.geometry.laplacian import mesh_operators
from app.geometry.topology import boundary_vertex_mask
from app.inference.correspondence import TemplateRegions
from app.inference.cover import REGION_ONLY_PREFIX, Cover, InvalidRegion, region_from_token, region_token, united
from app.inference.template import Template

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def regions() -> TemplateRegions:
    template = Template.load(MODELS)
    return TemplateRegions(template, mesh_operators(template.vertices, template.faces))


@pytest.fixture(scope="module")
def placed(regions) -> tuple[np.ndarray, Cover]:
    """The upper 40 % of the template, every vertex placed on itself with its own area, its
    raggedness its own (the share of its area on its boundary vertices, as PartInputs reads it)."""
    height = regions.tree.data[:, 2]
    mask = height >= np.quantile(height, 0.6)
    template = Template.load(MODELS)
    boundary = boundary_vertex_mask(template.faces[mask[template.faces].all(axis=1)], len(mask))
    area = regions.vertex_area
    return mask, regions.cover(np.flatnonzero(mask), area[mask], float(area[boundary].sum() / area[mask].sum()))


def test_a_region_placed_exactly_is_covered_by_its_own_area(regions, placed):
    mask, cover = placed
    area = regions.vertex_area
    assert cover.share.min() >= 0 and cover.share.max() <= 1
    # measured +3.2 %: the outline, where the heat step leaves half the density, counts over the full one
    assert float(cover.share @ area) == pytest.approx(float(area[mask].sum()), rel=0.04)
    points = regions.tree.data
    depth, _ = cKDTree(points[~mask]).query(points[mask])
    distance, _ = cKDTree(points[mask]).query(points[~mask])
    assert np.all(cover.share[mask][depth > 0.10] == 1.0)
    assert np.all(cover.share[~mask][distance > 0.15] < 0.01)


def test_a_token_gives_back_its_cover(placed):
    mask, cover = placed
    back = region_from_token(region_token(cover), len(mask), "token")
    np.testing.assert_array_equal(back.region, cover.region)
    assert np.abs(back.share - cover.share).max() <= 0.5 / 15 + 1e-12


def test_an_odd_template_s_token_gives_back_its_cover():
    region = np.array([True, False, True, True, False])
    cover = Cover(region, np.array([1.0, 0.2, 0.6, 0.0, 1 / 15]))
    back = region_from_token(region_token(cover), 5, "token")
    np.testing.assert_array_equal(back.region, region)
    np.testing.assert_allclose(back.share, [1.0, 3 / 15, 9 / 15, 0.0, 1 / 15])


def test_a_region_only_token_reads_as_its_region_fully_covered():
    region = np.array([True, False, True, True, False, False, False, False, True])
    token = REGION_ONLY_PREFIX + base64.b64encode(np.packbits(region).tobytes()).decode("ascii")
    back = region_from_token(token, len(region), "token")
    np.testing.assert_array_equal(back.region, region)
    np.testing.assert_array_equal(back.share, region.astype(float))


@pytest.mark.parametrize("vertices", [8, 12])
def test_a_token_of_another_template_or_of_nothing_is_refused(vertices):
    cover = Cover.of_region(np.ones(10, bool))
    with pytest.raises(InvalidRegion, match="bytes"):
        region_from_token(region_token(cover), vertices, "token")
    with pytest.raises(InvalidRegion, match="empty"):
        region_from_token(region_token(Cover.of_region(np.zeros(vertices, bool))), vertices, "token")


def test_the_union_s_cover_is_the_union_of_regions_and_the_larger_share():
    a = Cover(np.array([True, False, False]), np.array([1.0, 0.4, 0.0]))
    b = Cover(np.array([False, True, False]), np.array([0.2, 1.0, 0.1]))
    both = united([a, b])
    np.testing.assert_array_equal(both.region, [True, True, False])
    np.testing.assert_array_equal(both.share, [1.0, 1.0, 0.1])


def test_a_ragged_part_s_share_is_read_against_a_higher_full_density(regions, placed):
    """The same places read as a ragged part (a camera view's outline, its density spilling into
    its gaps) cover less of the template than as a compact one, and never more than its region."""
    mask, _ = placed
    index, area = np.flatnonzero(mask), regions.vertex_area[mask]
    compact, ragged = regions.cover(index, area, 0.0), regions.cover(index, area, 0.2)
    np.testing.assert_array_equal(compact.region, ragged.region)
    assert np.all(ragged.share <= compact.share) and float(ragged.share @ regions.vertex_area) < float(
        compact.share @ regions.vertex_area
    )
