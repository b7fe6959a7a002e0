"""Symmetry-aware scores of predicted template masks against the true ones, weighted by vertex area.

Spectra cannot tell a region from its mirror image, so every score takes the better of the
true mask and its mirror (the paper's rule: the orientation with the higher IoU, the same one
for every score of a row); areas, not vertex counts, measure size because the template's
triangles are far from uniform (a hand has five times a thigh's vertices).
"""

from dataclasses import dataclass, fields

import numpy as np

from app.inference import PART_NAMES, part_coverage, turned_towards

SERVED_LOCALIZER = "all"  # the localizer trained on every training identity, the one the service loads
PARTS_UNITED = "parts_united"  # the served localizer on each part, the two regions united
# What the service answers (app.inference.template.localized_region): expected-area regions by
# the served localizer, the union's grown to hold each part's own.
UNION_WITH_PARTS = "union_with_parts"


@dataclass(frozen=True)
class MaskScores:
    """Per row: symmetric IoU, area accuracy, and the mean absolute error of the covered share of
    each body part (what a front-end's "still missing" list reads), all as fractions."""

    iou: np.ndarray
    accuracy: np.ndarray
    coverage_error: np.ndarray


def present_part_coverage(masks: np.ndarray, weights: np.ndarray, labels: np.ndarray) -> np.ndarray:
    """(..., present parts) the covered share of each body part the template has (a test
    template may lack some), for masks (..., n), boolean or each vertex's covered share."""
    present = np.bincount(labels, minlength=len(PART_NAMES)) > 0
    return part_coverage(masks, weights, labels)[..., present]


def symmetric_scores(
    predicted: np.ndarray, truth: np.ndarray, weights: np.ndarray, mirror: np.ndarray, labels: np.ndarray
) -> MaskScores:
    """Scores of (m, n) boolean masks, each row against the better orientation of its truth;
    ``labels`` are the template's part labels."""
    w = weights / weights.sum()
    predicted_coverage = present_part_coverage(predicted, weights, labels)
    orientations = []
    for target in (truth, truth[:, mirror]):
        intersection = (predicted & target) @ w
        union = (predicted | target) @ w
        orientations.append(
            MaskScores(
                iou=np.where(union > 0, intersection / np.maximum(union, 1e-12), 1.0),
                accuracy=(predicted == target) @ w,
                coverage_error=np.abs(predicted_coverage - present_part_coverage(target, weights, labels)).mean(1),
            )
        )
    direct, mirrored = orientations
    better = mirrored.iou > direct.iou
    chosen = (np.where(better, getattr(mirrored, f.name), getattr(direct, f.name)) for f in fields(MaskScores))
    return MaskScores(*chosen)


def united_by_mirror_rule(first: np.ndarray, second: np.ndarray, weights: np.ndarray, mirror: np.ndarray) -> np.ndarray:
    """(m, n) union of two parts' localized masks, the second in the orientation that overlaps the
    first more: each is right only up to left/right, and parts of one scan overlap or touch."""
    return first | turned_towards(first, second, weights, mirror)
