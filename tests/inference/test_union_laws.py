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


@pytest.fixture(scope="module")
def laws() -> dict[str, list[float]]:
    models = SpectralModels(MODELS)
    return measure_laws(models, law_parts(RegionSampler(Template.load(MODELS))))


def test_a_part_united_with_itself_is_itself(laws):
    """Idempotence, U(A, A) = A (goal: within 0.5 %): measured worst …."""
    assert max(laws["idempotence"]) <= IDEMPOTENCE


def test_a_part_united_with_itself_re_meshed_is_itself(laws):
    """U(A, A′) ≈ A for A′ the same region re-meshed: measured mean …."""
    assert np.mean(laws["same_region"]) <= SAME_REGION


def test_a_part_inside_another_adds_nothing(laws):
    """Absorption, U(A, B) = B for A ⊂ B, regions and camera close-ups: measured mean …."""
    assert np.mean(laws["absorption"]) <= ABSORPTION


def test_a_part_united_with_the_whole_body_is_the_whole_body(laws):
    """U(A, body) = body: λ₁ stays 0 (measured …) and λ₂… within … (measured mean …)."""
    assert max(laws["whole_body_lambda1"]) <= 1e-3
    assert np.mean(laws["whole_body"]) <= WHOLE_BODY


def test_a_union_is_never_above_either_part(laws):
    """Monotonicity, λᵢ(A ∪ B) ≤ min(λᵢ(A), λᵢ(B)), for real parts and arbitrary spectra."""
    assert max(laws["excess_over_minimum"]) <= 1e-5
