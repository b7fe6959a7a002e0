"""The served models and the README's two sample parts solved and placed as uploads are, for the
session tests that fold or fuse real parts."""

import pytest

from app.core.config import Settings
from app.geometry.pipeline import Solved, SpectrumOptions, solve_bytes
from app.inference.correspondence import PlacedPart
from app.inference.models import SpectralModels
from app.inference.template import Template
from app.samples import PARTS, template_part


@pytest.fixture(scope="module")
def models() -> SpectralModels:
    return SpectralModels(Settings().models_dir)


@pytest.fixture(scope="module")
def sample_parts(models) -> list[tuple[str, Solved, PlacedPart]]:
    """Each sample part's name, solve and placing."""
    template = Template.load(Settings().models_dir)
    out = []
    for name, removed in PARTS.items():
        solved = solve_bytes(
            template_part(template, removed), "ply", SpectrumOptions(k=models.k), vectors=False, descriptors=True
        )
        out.append((name, solved, models.correspondence.placed(solved.part)))
    return out
