"""A session whose views in their own frames did not all come together: the others fused, those
left out chained onto that union, σ the chain's and the aligned band's together (hand-checked
composition), on two parts of the template body placed as uploads are."""

import numpy as np
import pytest

from app.sessions.aligned import AlignedUnion
from app.sessions.session import chained_onto_aligned, session_union, session_view


@pytest.fixture(scope="module")
def views(sample_parts):
    return [session_view(name, solved, placed, []) for name, solved, placed in sample_parts]


def test_all_views_joined_is_the_aligned_union(models, views):
    solved = AlignedUnion(views[0].eigenvalues * 0.9, [0, 1])
    union = session_union(models, views, "aligned", solved)
    assert union.union_by == "aligned"
    np.testing.assert_array_equal(union.estimate.eigenvalues, solved.eigenvalues)
    np.testing.assert_allclose(union.estimate.sigma, models.sessions.aligned.sigma(solved.eigenvalues, 2))


def test_a_view_left_out_is_chained_onto_the_others_with_both_uncertainties(models, views):
    solved = AlignedUnion(views[0].eigenvalues, [0])
    union = session_union(models, views, "aligned", solved)
    chained = chained_onto_aligned(models, views, solved).estimate
    assert union.union_by == "aligned-and-chained" and len(union.overlaps_told) == 1
    np.testing.assert_array_equal(union.estimate.eigenvalues, chained.eigenvalues)
    band = models.sessions.aligned.sigma(chained.eigenvalues, 2)
    np.testing.assert_allclose(union.estimate.sigma**2, chained.sigma**2 + band**2)
    assert not np.allclose(chained.eigenvalues, solved.eigenvalues)  # the view left out counts
