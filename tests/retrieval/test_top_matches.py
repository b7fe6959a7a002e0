"""``top_matches`` ranks by a matrix product and measures only the rows rounding could misplace:
its answer must be, to the bit, the stable sort of every exact distance (``nearest_of``)."""

import numpy as np
import pytest

from app.retrieval.distance import SAMPLE_ROWS, SINGLE_BLOCK_ROWS, features, nearest_of, top_matches
from tests.retrieval.test_stores import spectra


def _stable_truth(queries: np.ndarray, stored: np.ndarray, top: int):
    distance, query = nearest_of(queries, stored)
    order = np.argsort(distance, kind="stable")[:top]
    return order, distance[order], query[order]


@pytest.mark.parametrize("scale", [1.0, 1e-6, 1e12])  # bodies in metres, a shape 1 µm across, 1e12 1/m²
@pytest.mark.parametrize("queries", [1, 11])
@pytest.mark.parametrize("top", [1, 10, 57, 500])
def test_top_matches_is_the_stable_sort_of_every_exact_distance(scale, queries, top):
    rng = np.random.default_rng(int(queries * top))
    stored = spectra(300, 20) * scale
    stored = np.concatenate([stored, stored[:40], stored[rng.integers(300, size=20)] * 1.0000001])  # ties
    asked = np.concatenate([stored[[3, 150]], spectra(queries, 21) * scale])[:queries]  # exact matches
    if queries > 1:
        asked = asked * np.linspace(1.0, 0.7, queries)[:, None]
    stored_features = features(stored)
    ranked = top_matches(asked, stored_features, (stored_features**2).sum(axis=1), top)
    rows, distances, nearest = _stable_truth(asked, stored, top)
    np.testing.assert_array_equal(ranked.rows, rows)
    np.testing.assert_array_equal(ranked.distances, distances)
    np.testing.assert_array_equal(ranked.queries, nearest)


def test_a_stored_copy_of_the_query_is_at_distance_zero():
    """Exactly zero, as a difference gives: |f|² − 2 f·q + |q|² alone leaves ~1e-7 after the root."""
    stored = spectra(50, 22)
    stored_features = features(stored)
    ranked = top_matches(stored[17], stored_features, (stored_features**2).sum(axis=1), 3)
    assert ranked.rows[0] == 17 and ranked.distances[0] == 0.0


def test_rows_nearer_than_rounding_are_still_ranked_exactly():
    """Thirty copies of one body, each moved by ~1e-14 of its eigenvalues, all nearest the query:
    the matrix product cannot order them (its rounding is ~1e-13 of the squared distance), the
    exact distances can; the top 10 must be theirs."""
    rng = np.random.default_rng(23)
    body = spectra(1, 24)[0]
    copies = body * (1 + 1e-14 * rng.standard_normal((30, len(body))))
    stored = np.concatenate([spectra(200, 25) * 3, copies])
    stored_features = features(stored)
    query = body * 1.02
    ranked = top_matches(query, stored_features, (stored_features**2).sum(axis=1), 10)
    rows, distances, _ = _stable_truth(query, stored, 10)
    np.testing.assert_array_equal(ranked.rows, rows)
    np.testing.assert_array_equal(ranked.distances, distances)


@pytest.mark.parametrize("queries", [1, 11])
def test_a_store_larger_than_the_sample_is_ranked_exactly(queries):
    """Past SAMPLE_ROWS rows the candidates' bound comes from a sample: the answer is still the
    exact stable sort, near-ties included."""
    rng = np.random.default_rng(26)
    body = spectra(1, 27)[0]
    copies = body * (1 + 1e-14 * rng.standard_normal((30, len(body))))
    stored = np.concatenate([spectra(5 * SAMPLE_ROWS, 28), copies, spectra(SAMPLE_ROWS, 29)])
    asked = (body * 1.02)[None] * np.linspace(1.0, 0.8, queries)[:, None]
    stored_features = features(stored)
    for top in (1, 10, 25, 100):
        ranked = top_matches(asked, stored_features, (stored_features**2).sum(axis=1), top)
        rows, distances, nearest = _stable_truth(asked, stored, top)
        np.testing.assert_array_equal(ranked.rows, rows)
        np.testing.assert_array_equal(ranked.distances, distances)
        np.testing.assert_array_equal(ranked.queries, nearest)


@pytest.mark.parametrize("queries", [1, 3])
def test_rows_past_one_block_are_all_ranked(queries):
    """More rows than one block of either path holds: the last block's rows count like the first's."""
    stored = spectra(SINGLE_BLOCK_ROWS + 1000, 30)
    asked = stored[[-5, 10, -700][:queries]] * 1.001
    stored_features = features(stored)
    ranked = top_matches(asked, stored_features, (stored_features**2).sum(axis=1), 10)
    rows, distances, nearest = _stable_truth(asked, stored, 10)
    np.testing.assert_array_equal(ranked.rows, rows)
    np.testing.assert_array_equal(ranked.distances, distances)
    np.testing.assert_array_equal(ranked.queries, nearest)
