"""Baselines, metrics and mask scores against hand-checked cases (numpy only: run in CI)."""

import numpy as np
import pytest

from app.geometry.laplacian import mesh_operators
from app.geometry.spectrum import eigenvalues
from app.geometry.topology import boundary_vertex_mask
from app.inference.template import PART_NAMES
from tests.conftest import grid
from training.card.tables import per_eigenvalue_table
from training.localizer.masks import symmetric_scores, united_by_mirror_rule
from training.union.baselines import UnionLookup, disjoint_union, elementwise_min, larger_part


@pytest.fixture
def training_pairs():
    rng = np.random.default_rng(0)
    a = np.sort(rng.uniform(1, 300, (50, 20)), axis=1)
    b = np.sort(rng.uniform(1, 300, (50, 20)), axis=1)
    return a, b, np.minimum(a, b) * rng.uniform(0.5, 0.9, (50, 1))


def test_lookup_returns_the_union_of_a_training_pair_in_either_order(training_pairs):
    a, b, union = training_pairs
    lookup = UnionLookup(a, b, union)
    np.testing.assert_allclose(lookup.predict(a[:5], b[:5]), union[:5], rtol=1e-5)
    np.testing.assert_allclose(lookup.predict(b[:5], a[:5]), union[:5], rtol=1e-5)


def test_lookup_rescales_a_scaled_query(training_pairs):
    """Both parts 4 times larger in area: eigenvalues ÷ 4, and so is the looked-up union."""
    a, b, union = training_pairs
    lookup = UnionLookup(a, b, union)
    np.testing.assert_allclose(lookup.predict(a[:5] / 4, b[:5] / 4), union[:5] / 4, rtol=1e-5)


def test_min_and_larger_part():
    a = np.array([[1.0, 5.0], [2.0, 3.0]])
    b = np.array([[2.0, 4.0], [1.0, 9.0]])
    np.testing.assert_array_equal(elementwise_min(a, b), [[1, 4], [1, 3]])
    np.testing.assert_array_equal(larger_part(a, b, np.array([1.0, 0.2]), np.array([0.5, 0.7])), [[1, 5], [1, 9]])


def _dirichlet_spectrum(vertices: np.ndarray, faces: np.ndarray, k: int) -> np.ndarray:
    return eigenvalues(mesh_operators(vertices, faces), k, boundary_vertex_mask(faces, len(vertices)))


def test_disjoint_union_is_the_spectrum_of_two_parts_that_share_nothing():
    """The engine's Dirichlet spectrum of one mesh holding two separate patches (a square and a
    longer rectangle, side by side) is the baseline's merge of the patches' own spectra."""
    square, strip = grid(np.pi, np.pi, 24, 24), grid(2 * np.pi, np.pi, 40, 20)
    apart = strip.vertices + [4.0, 0.0, 0.0]
    faces = np.concatenate([square.faces, strip.faces + len(square.vertices)])
    both = (np.concatenate([square.vertices, apart]), faces)
    k = 12
    parts = [_dirichlet_spectrum(m.vertices, m.faces, k)[None] for m in (square, strip)]
    merged = disjoint_union(*parts)[0]
    np.testing.assert_allclose(_dirichlet_spectrum(*both, k), merged, rtol=1e-8)
    assert (merged <= elementwise_min(*parts)[0]).all() and (merged < elementwise_min(*parts)[0]).any()
    np.testing.assert_array_equal(disjoint_union(*parts), disjoint_union(*parts[::-1]))


def test_symmetric_scores_hand_checked():
    weights = np.array([1.0, 1.0, 2.0, 4.0])
    mirror = np.array([1, 0, 2, 3])  # vertices 0 and 1 swap sides
    labels = np.array([PART_NAMES.index(p) for p in ("left_hand", "right_hand", "torso", "torso")])
    truth = np.array([[True, False, True, False]] * 3)  # covers: left hand 1, right hand 0, torso 2/6
    predicted = np.array(
        [
            [False, True, True, False],  # the mirror image: perfect
            [True, False, False, False],  # 1 of 3 area units, everything else right but vertex 2
            [False, False, False, True],  # disjoint: the orientation as given is kept
        ]
    )
    scores = symmetric_scores(predicted, truth, weights, mirror, labels)
    np.testing.assert_allclose(scores.iou, [1.0, 1 / 3, 0.0])
    np.testing.assert_allclose(scores.accuracy, [1.0, 6 / 8, 1 / 8])
    # Covered shares (left hand, right hand, torso): predicted (0, 1, 1/3), (1, 0, 0), (0, 0, 4/6);
    # against the mirror (0, 1, 1/3), the truth (1, 0, 1/3), the truth; parts the template lacks don't count.
    np.testing.assert_allclose(scores.coverage_error, [0.0, (1 / 3) / 3, (1 + 1 / 3) / 3])


def test_parts_united_in_the_orientation_that_overlaps():
    weights = np.array([1.0, 1.0, 1.0, 1.0])
    mirror = np.array([1, 0, 3, 2])  # 0 ↔ 1 and 2 ↔ 3 swap sides
    first = np.array([[True, False, True, False], [True, False, False, False]])
    second = np.array([[False, True, False, True], [True, False, False, True]])
    # Row 0: the second part as given misses the first, mirrored it lies on it (0 and 2).
    # Row 1: as given it overlaps at vertex 0, mirrored ({1, 2}) not at all: kept as given.
    united = united_by_mirror_rule(first, second, weights, mirror)
    np.testing.assert_array_equal(united, [[True, False, True, False], [True, False, False, True]])


def test_retrieval_hit_rates_hand_checked():
    """Three people, two poses each; a query may not match the shape its scans came from."""
    from training.union.shapedna import hit_rates

    base = np.sort(np.random.default_rng(1).uniform(1, 50, 20))
    people = np.array([0, 0, 1, 1, 2, 2])
    stored = np.stack([base * s for s in (1.0, 1.01, 1.3, 1.31, 1.7, 1.71)])
    stored[:, 0] = 0  # closed bodies: λ₁ = 0, ignored by the distance
    queries = stored[[0, 2]] * 1.001
    rates = hit_rates(queries, people[[0, 2]], np.array([0, 2]), stored, people)
    assert rates == {"top1": 1.0, "top5": 1.0, "top10": 1.0}
    # Asked as person 2, the first query ranks person 0 and then person 1 above person 2 (4th).
    rates = hit_rates(queries[:1], np.array([2]), np.array([0]), stored, people)
    assert rates == {"top1": 0.0, "top5": 1.0, "top10": 1.0}


def test_per_eigenvalue_table_pools_rows_by_their_counts():
    def row(count: int, curve: list[float]) -> dict:
        return {"rows": count, "union": {"operator": {"mre_per_eigenvalue": curve}}}

    metrics = {
        "rows": {
            "test_a/known_man/mesh": row(1, [0.1, 0.2]),
            "test_a/unknown_man/mesh": row(3, [0.5, 0.2]),
            "test_a/child/mesh": row(100, [9.0, 9.0]),  # not a paper row: left out
            "test_b/known_man/mesh": row(2, [0.3, 0.0]),
        }
    }
    lines = per_eigenvalue_table(metrics, methods=("operator",))
    assert lines[0] == "| eigenvalue | test_a operator | test_b operator |"
    assert lines[2:] == ["| λ1 | 40.0 % | 30.0 % |", "| λ2 | 20.0 % | 0.0 % |"]
