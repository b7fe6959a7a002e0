"""The laws of union, as properties of the served ONNX operator (``models/union.onnx``).

Fresh parts of the shipped template body (:mod:`training.learning.laws`), through the service's
own model class. Tolerances are the committed model's measured figures (``python
benchmarks/bench_union_laws.py``) with a margin for other CPUs' rounding, never loosened to pass;
each docstring says what was measured.
"""

from pathlib import Path

import numpy as np
import pytest

from app.inference.models import SpectralModels
from training.data.regions import RegionSampler
from training.data.template import Template
from training.learning.laws import law_parts, measure_laws

MODELS = Path(__file__).resolve().parents[2] / "models"
# Measured on the committed models (2026-12-02), each with ~10 % margin. The goals of issue 16
# are tighter (U(A, A) within 0.5 %, U(A, A′) ≤ 2 %, U(A, B) ≈ B): not met yet, see the card.
IDEMPOTENCE = (0.037, 0.25)  # mean, worst; measured 0.0333, 0.2284 (previous model 0.285, 0.473)
SAME_REGION = 0.072  # mean; measured 0.0649 (previous 0.247)
ABSORPTION = 0.104  # mean; measured 0.0939 (previous 0.222)
WHOLE_BODY = 0.023  # mean over λ₂…λ₂₀; measured 0.0206 (previous 0.082, and λ₁ 0.14·λ₂ instead of 0)


@pytest.fixture(scope="module")
def laws() -> dict[str, list[float]]:
    models = SpectralModels(MODELS)
    return measure_laws(models, law_parts(RegionSampler(Template.load(MODELS))))


def test_a_part_united_with_itself_is_itself(laws):
    """Idempotence, U(A, A) = A (goal: within 0.5 %)."""
    assert np.mean(laws["idempotence"]) <= IDEMPOTENCE[0]
    assert max(laws["idempotence"]) <= IDEMPOTENCE[1]


def test_a_part_united_with_itself_re_meshed_is_itself(laws):
    """U(A, A′) ≈ A for A′ the same region re-meshed (goal: within the pose noise floor, 2 %)."""
    assert np.mean(laws["same_region"]) <= SAME_REGION


def test_a_part_inside_another_adds_nothing(laws):
    """Absorption, U(A, B) = B for A ⊂ B, regions and camera close-ups."""
    assert np.mean(laws["absorption"]) <= ABSORPTION


def test_a_part_united_with_the_whole_body_is_the_whole_body(laws):
    """U(A, body) = body: λ₁ stays 0 (measured exactly 0) and λ₂… close to the body's."""
    assert max(laws["whole_body_lambda1"]) <= 1e-3
    assert np.mean(laws["whole_body"]) <= WHOLE_BODY


def test_a_union_is_never_above_either_part(laws):
    """Monotonicity, λᵢ(A ∪ B) ≤ min(λᵢ(A), λᵢ(B)), for real parts and arbitrary spectra."""
    assert max(laws["excess_over_minimum"]) <= 1e-5
