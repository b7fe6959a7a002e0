"""Measured overlap of views in one frame, against rectangles whose shared area is known."""

import base64
from dataclasses import replace

import numpy as np
import pytest

from app.geometry.laplacian import mesh_operators
from app.geometry.overlap import (
    TOKEN_PREFIX,
    WIRE_POINTS,
    Footprint,
    footprint_from_token,
    footprint_of,
    footprint_token,
    measured_fold,
    measured_overlaps,
)
from app.geometry.shapes import Mesh
from app.geometry.topology import boundary_vertex_mask
from tests.conftest import grid


def view(width: float, height: float, cells_per_metre: int, shift: float = 0.0, lift: float = 0.0) -> Footprint:
    """A flat rectangular view, [shift, shift + width] × [0, height] at z = lift, meshed at its own
    density, its border its edge (as a solve marks its Dirichlet vertices)."""
    mesh = grid(width, height, int(width * cells_per_metre), int(height * cells_per_metre))
    vertices = mesh.vertices + np.array([shift, 0.0, lift])
    edge = boundary_vertex_mask(mesh.faces, len(vertices))
    return footprint_of(vertices, mesh_operators(vertices, mesh.faces).mass.diagonal(), edge=edge)


@pytest.mark.parametrize("densities", [(40, 40), (40, 57), (90, 33)])
def test_two_views_sharing_half_their_area_measure_a_half(densities):
    """Two 2 × 1 m views sharing 1 × 1 m, meshed alike or not: the smaller (either) is half inside,
    to 0.005 (0.0002–0.0023 measured): a point whose nearest other point is on the other's edge
    counts half. Without the edges the band one spacing wide past each edge counted whole
    (0.506–0.511 measured)."""
    first, second = view(2, 1, densities[0]), view(2, 1, densities[1], shift=1.0)
    (share,) = measured_overlaps([first, second])
    assert share == pytest.approx(0.5, abs=0.005)
    no_edges = [replace(v, edge=np.zeros_like(v.edge)) for v in (first, second)]
    assert measured_overlaps(no_edges)[0] > share + 0.004
    assert measured_overlaps([second, first]) == pytest.approx([share], abs=0.01)


def test_a_view_inside_another_is_whole_and_views_apart_share_nothing():
    large, inside = view(3, 1, 40), view(1, 0.6, 63, shift=1.0)
    assert measured_overlaps([large, inside]) == pytest.approx([1.0], abs=0.02)
    assert measured_overlaps([large, view(1, 1, 40, shift=3.5)]) == [0.0]
    assert measured_overlaps([large, view(3, 1, 40, lift=0.05)]) == [0.0]  # 5 cm off the surface


def test_a_chain_measures_each_view_against_the_union_so_far():
    """[0, 2], then [1, 3]: half; then [2.5, 3.5] against their union [0, 3] (3 m²): half of the
    1 m² view lies inside; the union so far counts the shared metre once."""
    views = [view(2, 1, 40), view(2, 1, 47, shift=1.0), view(1, 1, 40, shift=2.5)]
    assert measured_overlaps(views) == pytest.approx([0.5, 0.5], abs=0.03)


def test_a_large_view_is_subsampled_to_the_same_area():
    mesh: Mesh = grid(2, 1, 400, 200)
    areas = mesh_operators(mesh.vertices, mesh.faces).mass.diagonal()
    border = boundary_vertex_mask(mesh.faces, len(mesh.vertices))
    whole, kept = footprint_of(mesh.vertices, areas), footprint_of(mesh.vertices, areas, limit=5_000, edge=border)
    assert len(mesh.vertices) > 32_768 and len(whole.points) == 32_768 and whole.area == pytest.approx(2.0, rel=1e-5)
    assert len(kept.points) == 5_000 and kept.area == pytest.approx(2.0, rel=1e-5)
    assert kept.edge.sum() == pytest.approx(border.sum() * 5_000 / len(mesh.vertices), rel=0.2)  # thinned alike
    (share,) = measured_overlaps([kept, view(2, 1, 40, shift=1.0)])
    assert share == pytest.approx(0.5, abs=0.03)


def test_a_long_chain_of_dense_views_keeps_its_union_bounded_and_its_shares_right():
    """Six 1 × 1 m views 0.5 m apart, each denser than a footprint keeps: every next view lies half
    inside the union so far, which is thinned as it grows (the shares stay those of the areas)."""
    views = [view(1, 1, 200, shift=0.5 * i) for i in range(6)]
    assert all(len(v.points) == 32_768 for v in views)
    assert measured_overlaps(views) == pytest.approx([0.5] * 5, abs=0.03)


def test_a_footprint_token_reads_back_as_the_footprint_it_was_made_of():
    small = view(2, 1, 40)  # 3 321 points: kept whole
    back = footprint_from_token(footprint_token(small))
    np.testing.assert_array_equal(back.points, small.points)
    np.testing.assert_array_equal(back.weights, small.weights)
    assert not back.spread.any()  # every point a vertex of the mesh
    np.testing.assert_array_equal(back.edge, small.edge)
    assert back.edge.sum() == 2 * (80 + 40)  # the rectangle's border


def test_a_large_view_s_token_is_thinned_and_measures_the_same_share():
    large, other = view(2, 1, 120), view(2, 1, 40, shift=1.0)
    back = footprint_from_token(footprint_token(large))
    assert len(large.points) > WIRE_POINTS == len(back.points) and back.area == pytest.approx(large.area, rel=1e-5)
    (share,) = measured_overlaps([back, other])
    assert share == pytest.approx(0.5, abs=0.03)


def test_a_chain_told_view_by_view_through_the_union_s_token_measures_what_all_at_once_does():
    """[0, 2], [1, 3], then [2.5, 3.5]: the second step measured from the first step's union
    token and the third view alone is the fold's (a half each time)."""
    views = [view(2, 1, 40), view(2, 1, 47, shift=1.0), view(1, 1, 40, shift=2.5)]
    first = measured_fold(views[:2])
    assert first.union.area == pytest.approx(3.0, rel=0.03)  # the shared metre counted once
    second = measured_fold([footprint_from_token(footprint_token(first.union)), views[2]])
    whole = measured_fold(views)
    assert first.overlaps + second.overlaps == pytest.approx(whole.overlaps, abs=0.02)
    assert first.overlaps + second.overlaps == pytest.approx([0.5, 0.5], abs=0.03)
    assert first.boundaries + second.boundaries == pytest.approx(whole.boundaries, abs=0.02)


# Boundary shares L(∂(A ∪ B)) / (L(∂A) + L(∂B)) of rectangles, by hand: where both views stop at one
# place (a shared stretch of border) the union stops there too, and that stretch counts once.
@pytest.mark.parametrize(
    ("views", "expected"),
    [
        ((view(2, 1, 40), view(2, 1, 47, shift=1.0)), [8 / 12]),  # [0, 3] × [0, 1] of two 6 m borders
        ((view(2, 1, 40), view(2, 1, 57)), [6 / 12]),  # one region scanned twice, meshed apart
        ((view(3, 1, 40), view(1, 0.6, 63, shift=1.0)), [8 / 11.2]),  # inside, on the larger's bottom border
        ((view(3, 1, 40), view(1, 1, 40, shift=3.5)), [1.0]),  # apart: every border stays
        ((view(2, 1, 40), view(2, 1, 47, shift=1.0), view(1, 1, 40, shift=2.5)), [8 / 12, 9 / 12]),  # a chain
    ],
)
def test_boundary_shares_of_rectangles_are_their_borders_lengths(views, expected):
    assert measured_fold(list(views)).boundaries == pytest.approx(expected, abs=0.03)


def test_views_without_an_edge_have_a_closed_union():
    closed = [replace(v, edge=np.zeros_like(v.edge)) for v in (view(2, 1, 40), view(2, 1, 40, shift=1.0))]
    assert measured_fold(closed).boundaries == [0.0]


def _token(rows: np.ndarray) -> str:
    return TOKEN_PREFIX + base64.b64encode(np.asarray(rows, dtype="<f4").tobytes()).decode()


@pytest.mark.parametrize(
    ("token", "reason"),
    [
        ("AAAA", "not a footprint token"),
        (TOKEN_PREFIX + "not base64!", "not valid base64"),
        (TOKEN_PREFIX, "whole"),
        (TOKEN_PREFIX + base64.b64encode(b"\0" * 20).decode(), "whole"),
        (_token(np.ones((WIRE_POINTS + 1, 6))), f"more than {WIRE_POINTS}"),
        (_token([[0, 0, np.nan, 1, 0, 0]]), "not finite"),
        (_token([[0, 0, 0, np.inf, 0, 0]]), "not finite"),
        (_token([[0, 0, 0, 0, 0, 0]]), "not positive"),
        (_token([[0, 0, 0, -1, 0, 0]]), "not positive"),
        (_token([[0, 0, 0, 3e38, 0, 0]]), "sum past"),
        (_token([[3e38, 0, 0, 1, 0, 0]]), "beyond"),
        (_token([[0, 0, 0, 1, 3e38, 0]]), "beyond"),
        (_token([[0, 0, 0, 1, -1, 0]]), "negative spreads"),
        (_token([[0, 0, 0, 1, 0, 0.5]]), "edge flags"),
    ],
)
def test_what_is_not_a_footprint_token_says_why(token, reason):
    with pytest.raises(ValueError, match=reason):
        footprint_from_token(token)
