"""The union operator's memory of stored pairs: found in either order and at any scale, its
nearest others in order, and a large one's shortlist as exact as a full float64 search."""

import pytest

torch = pytest.importorskip("torch")

from tests.training.spectra import relative_logs, spectra  # noqa: E402
from training.union.memory import UnionMemory, common_scale  # noqa: E402


def test_memory_finds_a_stored_pair_in_either_order_and_at_any_scale():
    a, b, union = spectra(30, 10), spectra(30, 11), spectra(30, 12)
    memory = UnionMemory(a, b, union)
    for factor in (1.0, 0.05, 40.0):
        for first, second in ((a, b), (b, a)):
            prior, distance, _ = memory(first * factor, second * factor, 1)
            scale = common_scale(first * factor, second * factor)
            torch.testing.assert_close(prior[:, 0] * scale, union * factor, rtol=1e-5, atol=0)
            assert (distance < 1e-2).all()


def test_memory_returns_the_nearest_other_pairs_in_order():
    """With its own row hidden, a stored pair gets the unions of the nearest other pairs."""
    a, b, union = spectra(30, 13), spectra(30, 14), spectra(30, 15)
    memory = UnionMemory(a, b, union)
    za, zb = relative_logs(a, b)
    priors, distances, floors = memory(a, b, 3, torch.eye(30, dtype=torch.bool))
    forward = torch.cdist(torch.cat([za, zb], 1), memory.keys)
    backward = torch.cdist(torch.cat([zb, za], 1), memory.keys)
    expected, nearest = torch.minimum(forward, backward).fill_diagonal_(torch.inf).topk(3, largest=False)
    torch.testing.assert_close(priors, memory.unions[nearest])
    torch.testing.assert_close(distances, expected, rtol=1e-4, atol=1e-3)
    keys = memory.keys[nearest]
    torch.testing.assert_close(floors, torch.minimum(keys[..., :20], keys[..., 20:]))


def test_a_large_memory_finds_the_pairs_a_full_float64_search_finds():
    """400 stored pairs of nearly one spectrum twice (0.1 % apart, so either operand order may be
    the nearer, and more near neighbours than the float32 shortlist holds), each stored twice,
    among 1 600 pairs whose second part is 5× the first's eigenvalues: the neighbours and
    distances are those of a float64 search over every row in both orders (ties to the earlier
    row, by the memory's tie-break)."""
    generator = torch.Generator().manual_seed(7)

    def near(count: int) -> torch.Tensor:
        return torch.sort(spectra(1, 20) * (1 + 1e-3 * torch.randn(count, 20, generator=generator)), dim=1).values

    near_a, near_b = near(400), near(400)
    near_a[1::2], near_b[1::2] = near_a[::2], near_b[::2]  # each pair stored twice
    a, b = torch.cat([near_a, spectra(1600, 21)]), torch.cat([near_b, spectra(1600, 22) * 5])
    memory = UnionMemory(a, b, spectra(2000, 23))
    queries_a, queries_b = torch.cat([near(40), b[400::100]]), torch.cat([near(40), a[400::100] * 1.0001])
    forward = memory.queries(queries_a, queries_b)
    backward = torch.cat([forward[:, 20:], forward[:, :20]], dim=1)
    keys = memory.keys.double().T
    every_row = torch.minimum(memory.key_norms - 2 * forward @ keys, memory.key_norms - 2 * backward @ keys)
    expected, rows = (every_row + memory.tie_break).topk(5, largest=False)
    query_norm = (forward**2).sum(1, keepdim=True)
    priors, distances, _ = memory(queries_a, queries_b, 5)
    torch.testing.assert_close(priors, memory.unions[rows], rtol=0, atol=0)
    torch.testing.assert_close(distances, (expected + query_norm).sqrt().float())
