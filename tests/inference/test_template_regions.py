"""Regions on the template from placed vertices, and overlaps read on them (hand-checked cases)."""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from app.geometry.laplacian import mesh_operators
from app.inference.correspondence import TemplateRegions
from app.inference.template import Template

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def regions() -> TemplateRegions:
    template = Template.load(MODELS)
    return TemplateRegions(template, mesh_operators(template.vertices, template.faces))


def _plane(regions: TemplateRegions, axis: int, share: float) -> np.ndarray:
    values = regions.tree.data[:, axis]
    return values >= np.quantile(values, 1 - share)


def _iou(regions: TemplateRegions, a: np.ndarray, b: np.ndarray) -> float:
    area = regions.vertex_area
    return float(area[a & b].sum() / area[a | b].sum())


def test_a_region_placed_exactly_is_covered_with_its_outline_kept(regions):
    """Every vertex placed on itself with its own area: the region is the part's, its outline
    neither grown nor shrunk by more than the heat step's reach (a few template edges)."""
    mask = _plane(regions, 2, 0.4)
    covered = regions.cover(np.flatnonzero(mask), regions.vertex_area[mask]).region
    assert _iou(regions, covered, mask) > 0.95
    distance, _ = cKDTree(regions.tree.data[mask]).query(regions.tree.data[covered ^ mask])
    assert distance.max() <= 0.05


def test_a_sparsely_placed_part_is_closed_into_its_region(regions):
    """A coarse part (a quarter of the region's vertices placed, at random, each carrying four
    vertices' area) covers its region, not a scatter of points."""
    mask = _plane(regions, 2, 0.4)
    rng = np.random.default_rng(0)
    sparse = rng.choice(np.flatnonzero(mask), size=mask.sum() // 4, replace=False)
    covered = regions.cover(sparse, 4 * regions.vertex_area[sparse]).region
    assert _iou(regions, covered, mask) > 0.95


def test_the_region_does_not_depend_on_the_part_s_scale(regions):
    """A bigger person's part (all areas ×2.5, or ×0.4) covers the same template region."""
    mask = _plane(regions, 0, 0.3)
    index, area = np.flatnonzero(mask), regions.vertex_area[mask]
    same = regions.cover(index, area).region
    for factor in (2.5, 0.4):
        assert _iou(regions, regions.cover(index, factor * area).region, same) > 0.97


def test_a_part_of_a_few_vertices_still_covers_where_it_lands(regions):
    """Three vertices carry too little area to be dense anywhere: they cover where they land."""
    index = np.array([10, 2000, 4000])
    covered = regions.cover(index, np.full(3, 1e-6)).region
    assert np.flatnonzero(covered).tolist() == index.tolist()


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
