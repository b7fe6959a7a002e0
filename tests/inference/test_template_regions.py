"""Regions on the template from placed vertices, and overlaps read on them (hand-checked cases)."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from app.geometry.laplacian import mesh_operators
from app.inference.correspondence import CLOSING_M, REACH_M, TemplateRegions
from app.inference.template import Template

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def regions() -> TemplateRegions:
    template = Template.load(MODELS)
    return TemplateRegions(template, mesh_operators(template.vertices, template.faces).mass.diagonal())


def _plane(regions: TemplateRegions, axis: int, share: float) -> np.ndarray:
    values = regions.tree.data[:, axis]
    return values >= np.quantile(values, 1 - share)


def test_a_region_placed_exactly_is_reached_with_a_band_of_the_reach_around_it(regions):
    """Every place on a template vertex: the region is reached whole (closing is extensive: a
    vertex reached stays), and what is added lies within the reach (and closing) of it."""
    mask = _plane(regions, 2, 0.4)
    reached = regions.reached(regions.tree.data[mask])
    assert np.all(reached[mask])
    distance, _ = cKDTree(regions.tree.data[mask]).query(regions.tree.data[reached & ~mask])
    assert distance.max() <= REACH_M + CLOSING_M


def test_a_sparsely_placed_part_is_closed_into_its_region(regions):
    """A coarse part (a quarter of the template's vertices placed, at random) covers its region,
    not a scatter of points."""
    mask = _plane(regions, 2, 0.4)
    rng = np.random.default_rng(0)
    sparse = rng.choice(np.flatnonzero(mask), size=mask.sum() // 4, replace=False)
    reached = regions.reached(regions.tree.data[sparse])
    area = regions.vertex_area
    assert area[reached & mask].sum() > 0.98 * area[mask].sum()


def test_overlap_share_hand_checked(regions):
    top, upper = _plane(regions, 2, 0.3), _plane(regions, 2, 0.6)
    assert regions.overlap_share(top, upper) == pytest.approx(1.0)  # nested: all of the smaller inside
    assert regions.overlap_share(upper, top) == pytest.approx(1.0)  # symmetric
    assert regions.overlap_share(top, ~upper) == 0.0  # disjoint
    half = top & (regions.tree.data[:, 0] > 0)
    expected = regions.vertex_area[half].sum() / regions.vertex_area[half].sum()
    assert regions.overlap_share(half, top) == pytest.approx(expected)


def test_fold_reads_each_step_against_the_union_so_far(regions):
    a, b, c = _plane(regions, 2, 0.3), _plane(regions, 0, 0.5), ~_plane(regions, 2, 0.8)
    overlaps, boundaries = regions.fold([a, b, c])
    assert overlaps == pytest.approx([regions.overlap_share(a, b), regions.overlap_share(a | b, c)])
    assert len(boundaries) == 2 and all(0.0 <= share <= 1.0 for share in boundaries)
    same, same_boundary = regions.fold([a, a])
    assert same == [pytest.approx(1.0)] and same_boundary == [pytest.approx(0.5)]  # L(∂A) / (L(∂A) + L(∂A))


def test_shares_of_disjoint_regions_stay_within_their_range(regions):
    """Two regions that share nothing: nothing of either inside the other, and all of both
    boundaries left on the union's; the boundary share, a ratio of sums added in two orders, is
    held to 1 where rounding would put it past (what the union operator accepts)."""
    top, bottom = _plane(regions, 2, 0.2), ~_plane(regions, 2, 0.8)
    overlaps, boundaries = regions.fold([top, bottom])
    assert overlaps == [0.0]
    assert boundaries[0] <= 1.0 and boundaries[0] == pytest.approx(1.0)
