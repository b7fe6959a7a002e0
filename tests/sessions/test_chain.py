"""The one fold every union route answers with (:func:`app.sessions.chain.folded_union`), without a
server: shares the client told pass through as told, nothing known leaves every step untold, and
operands placed on the template are told what their places say, in either order alike (the
operator is commutative and an overlap is a property of the pair)."""

import numpy as np
import pytest

from app.sessions.chain import Located, folded_union


@pytest.fixture(scope="module")
def parts(sample_parts):
    """The sample parts as the fold reads them: (spectrum, where each lies)."""
    return [(np.asarray(solved.report.eigenvalues), Located.placed(placed)) for _, solved, placed in sample_parts]


def test_told_shares_pass_through_as_told(models, parts):
    (a, _), (b, _) = parts
    folded = folded_union(models, [a, b], None, [0.3], [0.1], "told")
    assert (folded.overlaps, folded.boundaries, folded.source) == ([0.3], [0.1], "told")
    assert (folded.told, folded.nested) == ([True], [False])
    np.testing.assert_array_equal(folded.result.eigenvalues, models.union([a, b], [0.3], [0.1], None).eigenvalues)


def test_nothing_known_leaves_every_step_untold(models, parts):
    (a, _), (b, _) = parts
    folded = folded_union(models, [a, b], None, None, None, None)
    assert (folded.overlaps, folded.boundaries, folded.source, folded.told, folded.nested) == ([], [], None, [], [])
    np.testing.assert_array_equal(folded.result.eigenvalues, models.union([a, b], None, None, None).eigenvalues)


def test_placed_operands_are_read_from_their_places_in_either_order(models, parts):
    (a, at_a), (b, at_b) = parts
    forward = folded_union(models, [a, b], [at_a, at_b], None, None, None)
    backward = folded_union(models, [b, a], [at_b, at_a], None, None, None)
    assert forward.source == backward.source == "correspondence"
    assert len(forward.overlaps) == len(forward.told) == len(forward.nested) == 1
    assert 0.5 < forward.overlaps[0] <= 1.0  # the two samples share most of the torso
    np.testing.assert_allclose(forward.overlaps, backward.overlaps, rtol=1e-9)
    np.testing.assert_allclose(forward.result.eigenvalues, backward.result.eigenvalues, rtol=1e-5)


def test_a_part_with_itself_overlaps_wholly(models, parts):
    (a, at_a), _ = parts
    folded = folded_union(models, [a, a], [at_a, at_a], None, None, None)
    assert folded.overlaps[0] == pytest.approx(1.0)
