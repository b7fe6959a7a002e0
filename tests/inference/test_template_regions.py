"""Regions on the template from placed vertices, and overlaps read on them (hand-checked cases)."""

from pathlib import Path

import numpy as np
import pytest

from app.geometry.laplacian import mesh_operators
from app.inference.correspondence import TemplateRegions
from app.inference.template import Template

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def regions() -> TemplateRegions:
    template = Template.load(MODELS)
    return TemplateRegions(template, mesh_operators(template.vertices, template.faces).mass.diagonal())


def _plane(regions: TemplateRegions, axis: int, share: float) -> np.ndarray:
    values = regions.tree.data[:, axis]
    return values >= np.quantile(values, 1 - share)


def test_every_vertex_reached_gives_at_least_the_region_and_little_more(regions):
    """Closing is extensive: a vertex reached stays (any vertex outside the grown region lies
    farther than the radius from it); it adds only what lies within the radius of two sides."""
    mask = _plane(regions, 2, 0.4)
    reached = regions.reached(np.flatnonzero(mask))
    assert np.all(reached[mask])
    area = regions.vertex_area
    assert area[reached & ~mask].sum() < 0.01 * area[mask].sum()


def test_a_sparsely_placed_part_is_closed_into_its_region(regions):
    """A coarse part (half the template's vertices reached, at random) covers its region, not a
    scatter of points."""
    mask = _plane(regions, 2, 0.4)
    rng = np.random.default_rng(0)
    sparse = rng.choice(np.flatnonzero(mask), size=mask.sum() // 2, replace=False)
    reached = regions.reached(sparse)
    area = regions.vertex_area
    assert area[reached & mask].sum() > 0.97 * area[mask].sum()
    assert area[reached & ~mask].sum() < 0.02 * area[mask].sum()


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
