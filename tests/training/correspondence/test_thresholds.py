"""The thresholds the correspondence pipeline writes into the graph, chosen on validation pairs:
hand-checked cases."""

import math

import pytest

pytest.importorskip("torch")  # the evaluation reads the training's parts loader

from training.correspondence.evaluate import (  # noqa: E402
    Thresholds,
    choose_thresholds,
    served_error,
    uncertain_threshold,
)


def _pair(measured: float, untold: float, told: float, nested: float, inner: float = math.inf) -> dict:
    return {
        "measured_overlap": measured,
        "untold": untold,
        "told_measured": told,
        "told_nested": nested,
        "inner_confidence": inner,
    }


def test_the_overlap_is_told_below_the_lowest_threshold_that_errs_least_then_nested_below_one():
    """A low measured overlap is worth telling, a near-total one not (its untold union is better);
    the third pair is worth telling from 0.7 on, so 0.7 is the lowest best; with it, the third pair
    told nested errs least, from the first confidence threshold above its 0.42: 0.45."""
    rows = [
        _pair(0.3, untold=0.10, told=0.02, nested=0.5),
        _pair(0.97, untold=0.02, told=0.05, nested=0.5),
        _pair(0.6, untold=0.2, told=0.1, nested=0.001, inner=0.42),
    ]
    chosen = choose_thresholds(rows)
    assert chosen == Thresholds(tell_below=0.7, nested_below=0.45)
    assert [served_error(row, chosen) for row in rows] == [0.02, 0.02, 0.001]


def test_a_part_is_warned_below_the_first_percentile_of_the_validation_parts_confidence():
    """100 parts at 0.01, 0.02, …, 1.00: the first percentile lies 0.99 of the way from the
    lowest to the next (NumPy's linear interpolation)."""
    confidences = [i / 100 for i in range(1, 101)]
    rows = [{"confidences": confidences[i : i + 2]} for i in range(0, 100, 2)]
    assert uncertain_threshold(rows) == pytest.approx(0.0199)
