"""Symmetry-aware overlap of predicted and true template masks, weighted by vertex area.

Spectra cannot tell a region from its mirror image, so every score takes the better of the
true mask and its mirror (the paper's rule); areas, not vertex counts, measure size because
the template's triangles are far from uniform (a hand has five times a thigh's vertices).
"""

import numpy as np


def symmetric_scores(
    predicted: np.ndarray, truth: np.ndarray, weights: np.ndarray, mirror: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """(IoU, accuracy) per row of (m, n) boolean masks, each against the better orientation."""
    w = weights / weights.sum()
    best_iou = np.full(len(predicted), -1.0)
    best_accuracy = np.zeros(len(predicted))
    for target in (truth, truth[:, mirror]):
        intersection = (predicted & target) @ w
        union = (predicted | target) @ w
        iou = np.where(union > 0, intersection / np.maximum(union, 1e-12), 1.0)
        accuracy = (predicted == target) @ w
        better = iou > best_iou
        best_iou = np.where(better, iou, best_iou)
        best_accuracy = np.where(better, accuracy, best_accuracy)
    return best_iou, best_accuracy
