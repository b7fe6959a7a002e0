"""A pair's overlap stratum, hand-checked at each edge of the strata."""

import numpy as np

from training.data.pairs import NESTED_SHARE, STRATA, overlap_strata


def test_each_pair_falls_in_the_first_stratum_that_applies():
    inside = np.array([1.0, 1.0, NESTED_SHARE, 0.979, 0.76, 0.75, 0.25, 0.249, 0.0])
    same_region = np.array([True, True, False, False, False, False, False, False, False])
    identical = np.array([True, False, False, False, False, False, False, False, False])
    labels = overlap_strata(inside, same_region, identical)
    assert labels.tolist() == [
        "identical",
        "same_region",
        "nested",
        "over_75",
        "over_75",
        "25_to_75",
        "25_to_75",
        "under_25",
        "under_25",
    ]
    assert set(labels) == set(STRATA)


def test_a_single_pair_gets_its_stratum_as_a_name():
    assert str(overlap_strata(np.array(0.5), np.array(False), np.array(False))) == "25_to_75"
