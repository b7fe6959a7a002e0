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
OVERLAP = "overlap"  # two parts of one region, overlapping anywhere from a band to nesting
AREA_TIE = 1e-3  # union areas closer than this fraction of the body are a tie
MIN_GAIN = 0.02  # full and partial pairs: each part adds this much of the body to the other (overlap pairs nest)
# A smaller part this much inside the other is nested in it: template masks of views are cut along
# triangle edges, so a close-up a camera takes inside a far view may poke out by a face.
NESTED_SHARE = 0.98
# Overlap strata: how much of the smaller part lies inside the other. "identical" is one spectrum
# twice (same region, body and meshing), "same_region" the region again in another pose or meshing.
STRATA = ("identical", "same_region", "nested", "over_75", "25_to_75", "under_25")


def overlap_strata(inside: np.ndarray, same_region: np.ndarray, identical: np.ndarray) -> np.ndarray:
    """The overlap stratum (a name of :data:`STRATA`) of each pair, from the share of its smaller
    part inside the other (``inside``) and whether its parts are one region (``same_region``),
    and that region on one body and meshing (``identical``): the first that applies."""
    return np.select(
        [identical, same_region, inside >= NESTED_SHARE, inside > 0.75, inside >= 0.25],
        list(STRATA[:5]),
        default=STRATA[5],
    )


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
    draw = {FULL_COVERAGE: full_coverage_pair, PARTIAL_UNION: partial_union_pair, OVERLAP: overlap_pair}[scenario]
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


def _field(sampler: RegionSampler, rng: np.random.Generator) -> np.ndarray:
    """A random low-frequency field on the template: where two parts of one union are cut apart."""
    count = int(rng.integers(1, 10))
    return sampler.basis[:, 1 : count + 1] @ rng.standard_normal(count)


def _cut(sampler: RegionSampler, union: np.ndarray, field: np.ndarray, low: float, high: float) -> Pair | None:
    """A keeps the field's low side up to quantile ``high``, B its high side from ``low``; the band
    between the two quantiles is their overlap. None if a side is not an admissible region."""
    levels = np.quantile(field[union], [low, high])
    a = sampler.clean(union & (field <= levels[1]))
    b = sampler.clean(union & (field >= levels[0]))
    if a is None or b is None or not np.array_equal(a | b, union):
        return None
    return resolve_symmetry(sampler, a, b)


def split_union(sampler: RegionSampler, union: np.ndarray, rng: np.random.Generator) -> Pair | None:
    """Two overlapping parts whose union is exactly ``union`` (or its mirror image), or None.

    A random low-frequency field is cut at two levels: A keeps the low side, B the high side,
    and the band between them is where they overlap. This is how Test B realizes one held-out
    union type many times, by parts that differ from row to row.
    """
    field = _field(sampler, rng)
    low = rng.uniform(0.2, 0.6)
    pair = _cut(sampler, union, field, low, low + rng.uniform(0.1, 0.3))
    if pair is None:
        return None
    same = np.array_equal(pair.union, union) or np.array_equal(pair.union, union[sampler.template.mirror])
    return pair if same and pair.scenario == PARTIAL_UNION and adds_to_both(sampler, pair) else None


def overlap_pair(sampler: RegionSampler, rng: np.random.Generator) -> Pair | None:
    """Two parts of one random region overlapping by anything from a thin band to all of the
    smaller one: the low quantile runs from 0 (B is the whole region, A inside it) to ½, the
    high one from just above it to 1. Consecutive scans overlap like this; random pairs don't."""
    union = sampler.sample(rng).mask
    low = rng.uniform(0.0, 0.5) if rng.random() < 0.8 else 0.0
    high = rng.uniform(low + 0.02, 1.0)
    pair = _cut(sampler, union, _field(sampler, rng), low, high)
    if pair is None or pair.scenario != PARTIAL_UNION or sampler.area_fraction(pair.union) > MAX_AREA_FRACTION:
        return None
    return pair if sampler.is_connected(pair.union) else None


def containment(sampler: RegionSampler, a: np.ndarray, b: np.ndarray) -> float:
    """The share of the smaller part's area that lies inside the other part (0 … 1)."""
    smaller = min(sampler.area_fraction(a), sampler.area_fraction(b))
    return sampler.area_fraction(a & b) / max(smaller, 1e-12)


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
