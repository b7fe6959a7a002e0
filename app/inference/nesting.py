"""Union steps told they are nested: where the spectra allow one operand inside the other and
its places are too uncertain to measure how much of it lies there.

Why: a part inside another (a close-up in its view) has the other's spectrum as its union, and
the union operator told an overlap of 1 answers it. Measured from places, a small part's
overlap is often far below 1 (the network places small parts worst), and an overlap told 0.2
too low costs a nested pair's union ten times its error. Dirichlet monotonicity gives a check
that needs no places: a part inside another has every eigenvalue at least the other's. So a
step is told nested where the operand whose eigenvalues all lie at or above the other's was
placed with a mean confidence below a threshold chosen on validation pairs (the graph's
metadata, :data:`NESTED_BELOW_KEY`); elsewhere the measured overlap stands.
"""

from dataclasses import dataclass

import numpy as np

# The graph's metadata key: a measured union step is told nested (overlap 1) where its inner
# candidate's mean place confidence is below this value (0: never).
NESTED_BELOW_KEY = "nested_below_confidence"
NESTED_OVERLAP = 1.0


@dataclass(frozen=True)
class Nesting:
    """What the union needs to tell a measured step nested: per operand, the area-weighted mean
    confidence of its places (1 where its region was carried, not placed here) and its own area
    (m², to weight a running union's confidence), and the threshold."""

    confidence: list[float]
    area: list[float]
    below: float

    def running_confidence(self, operands: int) -> float:
        """The area-weighted mean confidence of the first ``operands`` operands (a union so far)."""
        weights = np.asarray(self.area[:operands])
        return float(np.asarray(self.confidence[:operands]) @ weights / weights.sum())


def dominates(inner: np.ndarray, outer: np.ndarray) -> bool:
    """Whether every eigenvalue of ``inner`` is at least ``outer``'s: what a part lying inside
    another must show (Dirichlet monotonicity)."""
    return bool(np.all(inner >= outer))


def inner_confidence(nesting: Nesting, step: int, current: np.ndarray, other: np.ndarray) -> float:
    """The lowest place confidence among the operands of union step ``step`` (the union so far
    of operands 0 … step, spectrum ``current``, and operand step + 1, spectrum ``other``) that
    could lie inside the other, by their spectra; infinite where neither could."""
    candidates = [np.inf]
    if dominates(current, other):
        candidates.append(nesting.running_confidence(step + 1))
    if dominates(other, current):
        candidates.append(nesting.confidence[step + 1])
    return float(min(candidates))


def nested_step(nesting: Nesting, step: int, current: np.ndarray, other: np.ndarray) -> bool:
    """Whether union step ``step`` is told nested: an operand could lie inside the other and its
    places are uncertain (symmetric in the two, as the union is)."""
    return inner_confidence(nesting, step, current, other) < nesting.below
