"""Pairs (and triples) of partial regions with their union, under the paper's ambiguity rules.

The spectra of a region and of its mirror image are the same, so a learned union of two
spectra cannot know whether B or mirror(B) was meant. As in the paper, the ground truth is
made a function of the inputs: between A ∪ B and A ∪ mirror(B) take the smaller union, and
between a union and its mirror image prefer the one lying more on the body's left.
"""

from dataclasses import dataclass

import numpy as np

from training.data.regions import MAX_AREA_FRACTION, RegionSampler

FULL_COVERAGE = "full"
PARTIAL_UNION = "partial"
AREA_TIE = 1e-3  # union areas closer than this fraction of the body are a tie
MIN_GAIN = 0.02  # each part adds at least this fraction of the body to the other: no nested pairs


@dataclass(frozen=True)
class Pair:
    """Masks of two parts and of their union; ``scenario`` says whether the union is the body."""

    a: np.ndarray
    b: np.ndarray
    union: np.ndarray
    scenario: str


def resolve_symmetry(sampler: RegionSampler, a: np.ndarray, b: np.ndarray) -> Pair:
    """Apply the minimum-union-area rule to B, then the left preference to the whole pair."""
    mirror = sampler.template.mirror
    b_mirrored = b[mirror]
    area = sampler.area_fraction(a | b)
    area_mirrored = sampler.area_fraction(a | b_mirrored)
    if area_mirrored < area - AREA_TIE:
        b = b_mirrored
    union = a | b
    if sampler.left_fraction(union[mirror]) > sampler.left_fraction(union) + AREA_TIE:
        a, b, union = a[mirror], b[mirror], union[mirror]
    scenario = FULL_COVERAGE if union.all() else PARTIAL_UNION
    return Pair(a, b, union, scenario)


def adds_to_both(sampler: RegionSampler, pair: Pair) -> bool:
    """Neither part (nearly) contains the other, so the union is more than its larger part."""
    union = sampler.area_fraction(pair.union)
    return union - max(sampler.area_fraction(pair.a), sampler.area_fraction(pair.b)) >= MIN_GAIN


def full_coverage_pair(sampler: RegionSampler, rng: np.random.Generator) -> Pair | None:
    """A random part and a second one that covers the rest of the body with some overlap.

    B covers what A misses *and its mirror image*: otherwise A ∪ mirror(B) is smaller than the
    body and the minimum-area rule turns nine in ten such pairs into partial unions.
    """
    a = sampler.sample(rng).mask
    missed = ~(a & a[sampler.template.mirror])
    reach = rng.uniform(0.02, 0.2)
    b = sampler.clean(sampler.distances_from_set(np.flatnonzero(missed), limit=reach) <= reach)
    if b is None or not (a | b).all():
        return None
    pair = resolve_symmetry(sampler, a, b)
    return pair if pair.scenario == FULL_COVERAGE and adds_to_both(sampler, pair) else None


def partial_union_pair(sampler: RegionSampler, rng: np.random.Generator) -> Pair | None:
    """Two overlapping random parts whose union is one connected region short of the body."""
    a = sampler.sample(rng).mask
    b = sampler.sample(rng).mask
    if not (a & b).any():
        return None
    pair = resolve_symmetry(sampler, a, b)
    if pair.scenario != PARTIAL_UNION or sampler.area_fraction(pair.union) > MAX_AREA_FRACTION:
        return None
    if not adds_to_both(sampler, pair):
        return None
    return pair if sampler.is_connected(pair.union) else None


def sample_pair(sampler: RegionSampler, rng: np.random.Generator, scenario: str) -> Pair:
    """Rejection-sample a pair of the given scenario."""
    draw = full_coverage_pair if scenario == FULL_COVERAGE else partial_union_pair
    while True:
        pair = draw(sampler, rng)
        if pair is not None:
            return pair


def sample_triple(sampler: RegionSampler, rng: np.random.Generator) -> tuple[Pair, Pair]:
    """(A ∪ B) then ((A ∪ B) ∪ C), each resolved by the same rules, for chained unions."""
    while True:
        first = sample_pair(sampler, rng, PARTIAL_UNION)
        c = sampler.sample(rng).mask
        if not (first.union & c).any():
            continue
        second = resolve_symmetry(sampler, first.union, c)
        if np.array_equal(second.a, first.union) and sampler.is_connected(second.union):
            return first, second


def split_union(sampler: RegionSampler, union: np.ndarray, rng: np.random.Generator) -> Pair | None:
    """Two overlapping parts whose union is exactly ``union`` (or its mirror image), or None.

    A random low-frequency field is cut at two levels: A keeps the low side, B the high side,
    and the band between them is where they overlap. This is how Test B realizes one held-out
    union type many times, by parts that differ from row to row.
    """
    count = int(rng.integers(1, 10))
    field = sampler.basis[:, 1 : count + 1] @ rng.standard_normal(count)
    low = rng.uniform(0.2, 0.6)
    levels = np.quantile(field[union], [low, low + rng.uniform(0.1, 0.3)])
    a = sampler.clean(union & (field <= levels[1]))
    b = sampler.clean(union & (field >= levels[0]))
    if a is None or b is None or not np.array_equal(a | b, union):
        return None
    pair = resolve_symmetry(sampler, a, b)
    same = np.array_equal(pair.union, union) or np.array_equal(pair.union, union[sampler.template.mirror])
    return pair if same and pair.scenario == PARTIAL_UNION and adds_to_both(sampler, pair) else None


def symmetric_iou(masks: np.ndarray, others: np.ndarray, weights: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """(len(masks),) largest area-weighted IoU of each mask with any of ``others`` or their mirrors."""
    if len(others) == 0:
        return np.zeros(len(masks))
    queries = masks.astype(np.float32)
    candidates = np.concatenate([others, others[:, mirror]]).astype(np.float32)
    w = weights.astype(np.float32)
    intersection = (queries * w) @ candidates.T
    union = (queries @ w)[:, None] + (candidates @ w)[None, :] - intersection
    return (intersection / np.maximum(union, 1e-12)).max(axis=1)
