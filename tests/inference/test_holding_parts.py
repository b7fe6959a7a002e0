"""``holding_parts``: a localized union grown to hold its parts' regions, each turned to its side."""

import numpy as np

from app.inference.template import holding_parts, turned_towards

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
