"""A chain's σ carries its inner union's uncertainty (app.inference.models.chained_sigma)."""

import numpy as np

from app.inference.models import chained_sigma


def test_exact_operands_keep_the_step_sigma():
    inner, union, step = np.array([1.0, 4.0, 9.0]), np.array([0.5, 3.0, 8.0]), np.array([0.1, 0.2, 0.3])
    np.testing.assert_array_equal(chained_sigma(inner, np.zeros(3), union, step), step)


def test_where_nothing_is_added_the_inner_uncertainty_passes_whole():
    """U(inner, C) = inner with an exact step: the union is off exactly as the inner union is."""
    inner, inner_sigma = np.array([2.0, 5.0, 7.0]), np.array([0.2, 1.0, 0.7])
    np.testing.assert_allclose(chained_sigma(inner, inner_sigma, inner, np.zeros(3)), inner_sigma)


def test_independent_errors_add_in_quadrature_and_scale_with_the_union():
    """An inner union 10 % uncertain leaves the new union (half its size) 10 % uncertain too;
    with the step's own 24 %: √(10² + 24²) = 26 %."""
    inner, union = np.array([10.0, 20.0]), np.array([5.0, 10.0])
    got = chained_sigma(inner, 0.1 * inner, union, 0.24 * union)
    np.testing.assert_allclose(got, 0.26 * union)


def test_a_zero_eigenvalue_stays_finite_and_never_carries_more_than_the_union():
    """A closed inner union has λ₁ = 0; its σ is carried as at most the whole union value."""
    got = chained_sigma(np.array([0.0, 3.0]), np.array([0.4, 0.3]), np.array([0.0, 2.0]), np.array([0.05, 0.1]))
    assert np.isfinite(got).all()
    np.testing.assert_allclose(got, [0.05, np.hypot(0.1, 0.2)])
