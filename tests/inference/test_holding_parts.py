"""``holding_parts``: a localized union grown to hold its parts' regions, each turned to its side."""

import numpy as np

from app.inference.template import expected_area_masks, holding_parts, localized_region, turned_towards

# Four template vertices of equal area: 0 ↔ 1 and 2 ↔ 3 are each other's mirror images.
AREA, MIRROR = np.ones(4), np.array([1, 0, 3, 2])


def masks(*rows: list[int]) -> np.ndarray:
    return np.array(rows, dtype=bool)


def test_a_part_is_turned_to_the_side_it_overlaps_and_kept_where_it_overlaps_neither():
    union = masks([1, 0, 1, 0])
    assert turned_towards(union, masks([0, 1, 0, 0]), AREA, MIRROR).tolist() == [[True, False, False, False]]
    assert turned_towards(union, masks([1, 0, 0, 0]), AREA, MIRROR).tolist() == [[True, False, False, False]]
    assert turned_towards(masks([0, 0, 0, 0]), masks([0, 0, 0, 1]), AREA, MIRROR).tolist() == [[False] * 3 + [True]]


def test_the_union_grows_by_its_parts_and_the_order_of_the_parts_does_not_matter():
    union, a, b = masks([1, 0, 0, 0]), masks([0, 1, 0, 1]), masks([0, 0, 1, 0])
    # a overlaps the union once turned (1 → 0, 3 → 2); b overlaps neither way and is kept.
    assert holding_parts(union, [a, b], AREA, MIRROR).tolist() == [[True, False, True, False]]
    assert np.array_equal(holding_parts(union, [a, b], AREA, MIRROR), holding_parts(union, [b, a], AREA, MIRROR))
    assert np.array_equal(holding_parts(union, [], AREA, MIRROR), union)


def test_an_expected_area_region_takes_the_most_probable_vertices_up_to_the_expected_area():
    areas = np.array([1.0, 2.0, 3.0, 4.0])
    # Expected area 0.9 + 0.2 + 1.5 = 2.6: vertex 0 (running area 0…1), then vertex 2 (1…4, its
    # midpoint 2.5 below 2.6), not vertex 1 (4…6).
    probability = np.array([[0.9, 0.1, 0.5, 0.0], [0.0, 0.0, 0.0, 0.0], [1.0, 0.0, 1.0, 1.0]])
    assert expected_area_masks(probability, areas).tolist() == [
        [True, False, True, False],
        [False, False, False, False],  # nothing expected, nothing in
        [True, False, True, True],  # a sure map is its own p ≥ 0.5 mask
    ]


def test_the_localized_region_of_one_operand_is_its_expected_area_region_and_a_union_holds_its_parts():
    union, part = np.array([[0.6, 0.0, 0.0, 0.0]]), np.array([[0.0, 0.0, 0.9, 0.0]])
    alone = localized_region(union, [], AREA, MIRROR)
    assert np.array_equal(alone, expected_area_masks(union, AREA))
    assert localized_region(union, [part], AREA, MIRROR).tolist() == [[True, False, True, False]]
