"""What a placed part covers (:mod:`app.inference.cover`): its covered share, and the token a
client keeps it by.

The truths: a region placed exactly, vertex on vertex, is covered in full inside and not at all
far from it, and its shares sum to its own area (its coverage is its own, to a few per cent); a
cover's bytes give back the cover they were made of (the share to its sixteenths); a cover of
another template, or of nothing, is refused.
"""

from pathlib import Path

import numpy as np
import pytest
from scipy.spatial import cKDTree

from app.geometry.laplacian import mesh_operators
from app.geometry.topology import boundary_vertex_mask
from app.inference.correspondence import TemplateRegions
from app.inference.cover import Cover, InvalidRegion, cover_bytes, cover_of_bytes, cover_of_text, cover_text, united
from app.inference.template import Template

MODELS = Path(__file__).resolve().parents[2] / "models"


@pytest.fixture(scope="module")
def regions() -> TemplateRegions:
    template = Template.load(MODELS)
    return TemplateRegions(template, mesh_operators(template.vertices, template.faces))


@pytest.fixture(scope="module")
def placed(regions) -> tuple[np.ndarray, Cover]:
    """The upper 40 % of the template, every vertex placed on itself with its own area, its
    boundary vertices flagged as PartInputs flags them."""
    mask = upper(regions)
    return mask, regions.cover(np.flatnonzero(mask), regions.vertex_area[mask], outline(mask)[mask])


def upper(regions: TemplateRegions) -> np.ndarray:
    height = regions.tree.data[:, 2]
    return height >= np.quantile(height, 0.6)


def outline(mask: np.ndarray) -> np.ndarray:
    """(n,) bool: the boundary vertices of the template's faces inside ``mask``."""
    faces = Template.load(MODELS).faces
    return boundary_vertex_mask(faces[mask[faces].all(axis=1)], len(mask))


def test_a_region_placed_exactly_is_covered_by_its_own_area(regions, placed):
    mask, cover = placed
    area = regions.vertex_area
    assert cover.share.min() >= 0 and cover.share.max() <= 1
    # measured -0.3 % (+2.7 % with the outline's area counted in full)
    assert float(cover.share @ area) == pytest.approx(float(area[mask].sum()), rel=0.04)
    points = regions.tree.data
    depth, _ = cKDTree(points[~mask]).query(points[mask])
    distance, _ = cKDTree(points[mask]).query(points[~mask])
    assert np.all(cover.share[mask][depth > 0.10] == 1.0)
    assert np.all(cover.share[~mask][distance > 0.15] < 0.01)


def test_a_stored_cover_gives_back_its_cover(placed):
    mask, cover = placed
    back = cover_of_text(cover_text(cover), len(mask), "token")
    np.testing.assert_array_equal(back.region, cover.region)
    assert np.abs(back.share - cover.share).max() <= 0.5 / 15 + 1e-12


def test_an_odd_template_s_cover_gives_back_its_cover():
    region = np.array([True, False, True, True, False])
    cover = Cover(region, np.array([1.0, 0.2, 0.6, 0.0, 1 / 15]))
    back = cover_of_bytes(cover_bytes(cover), 5, "token")
    np.testing.assert_array_equal(back.region, region)
    np.testing.assert_allclose(back.share, [1.0, 3 / 15, 9 / 15, 0.0, 1 / 15])


@pytest.mark.parametrize("vertices", [8, 12])
def test_a_cover_of_another_template_or_of_nothing_is_refused(vertices):
    cover = Cover.of_region(np.ones(10, bool))
    with pytest.raises(InvalidRegion, match="bytes"):
        cover_of_bytes(cover_bytes(cover), vertices, "token")
    with pytest.raises(InvalidRegion, match="empty"):
        cover_of_bytes(cover_bytes(Cover.of_region(np.zeros(vertices, bool))), vertices, "token")


def test_the_union_s_cover_is_the_union_of_regions_and_the_larger_share():
    a = Cover(np.array([True, False, False]), np.array([1.0, 0.4, 0.0]))
    b = Cover(np.array([False, True, False]), np.array([0.2, 1.0, 0.1]))
    both = united([a, b])
    np.testing.assert_array_equal(both.region, [True, True, False])
    np.testing.assert_array_equal(both.share, [1.0, 1.0, 0.1])


def test_an_outline_placed_astray_covers_less_where_it_landed(regions):
    """A part's boundary vertices are placed worst: the upper 40 % with its outline's places sent
    to the feet covers less there flagged as outline than read as interior (measured 0.0056
    against 0.0113 m² of region, 0.0050 against 0.0125 m² of shares)."""
    mask = upper(regions)
    height = regions.tree.data[:, 2]
    index, area, flags = np.flatnonzero(mask), regions.vertex_area[mask], outline(mask)[mask]
    feet = np.flatnonzero(height <= np.quantile(height, 0.05))
    astray = index.copy()
    astray[flags] = feet[np.arange(flags.sum()) % len(feet)]
    low = height <= np.quantile(height, 0.1)
    read = {name: regions.cover(astray, area, given) for name, given in (("interior", None), ("outline", flags))}
    region_there = {name: float(regions.vertex_area[cover.region & low].sum()) for name, cover in read.items()}
    share_there = {name: float(cover.share[low] @ regions.vertex_area[low]) for name, cover in read.items()}
    assert region_there["outline"] < 0.7 * region_there["interior"]
    assert share_there["outline"] < 0.7 * share_there["interior"]
