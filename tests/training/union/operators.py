"""Union operators with random weights over a random memory, and what tests tell them: the laws
hold whatever the weights (shared by the union model's tests)."""

import torch

from tests.training.spectra import spectra
from training.union.config import MONOTONE, PRIOR, UnionConfig
from training.union.corrections import ToldCorrection
from training.union.memory import UnionMemory
from training.union.net import UnionOperator

CORRECTIONS = ("deepsets", "transformer")
PARAMETRIZATIONS = (PRIOR, MONOTONE)


# The blend of the network's decrease with the neighbours' (UnionOperator.blended): unfitted (w = 0),
# and weights that give every pair a weight of its own between 0 and 1.
BLENDS = (None, (0.5, -2.0, 1.0, 0.3, 4.0))
# What the correction reads beside the operands and the memory: nothing more, the operands' disjoint
# union, or that and the overlap a caller tells (random shares, a third of them unknown), the told
# pairs answered by the correction or by a told specialist (ToldCorrection) of random weights, and
# those told their boundary share too (random shares, every other one unknown) by a second one.
READS = ("plain", "disjoint", "told", "told_specialist", "told_boundary")


def told_overlaps(count: int, seed: int) -> torch.Tensor:
    """(count, 1) overlaps as callers tell them: shares in 0 … 1, every third one unknown (−1)."""
    shares = torch.rand(count, 1, generator=torch.Generator().manual_seed(seed))
    shares[::3] = -1.0
    return shares


def operator(
    correction: str,
    seed: int = 0,
    stored: int = 50,
    parametrization: str = MONOTONE,
    blend: tuple[float, ...] | None = None,
    reads: str = "plain",
) -> UnionOperator:
    """An operator with random weights (the correction's zero-initialised last layer too) over a
    random memory, its blend set to ``blend`` (unfitted for None), reading what ``reads`` says
    (a name of READS)."""
    memory = UnionMemory(spectra(stored, 100 + seed), spectra(stored, 200 + seed), spectra(stored, 300 + seed) / 2)
    torch.manual_seed(seed)
    config = UnionConfig(
        correction=correction,
        parametrization=parametrization,
        disjoint_prior=reads != "plain",
        overlap_hint=reads.startswith("told"),
    )
    model = UnionOperator(config, memory)
    last = model.correction.rho if correction == "transformer" else model.correction.head[-1]
    torch.nn.init.normal_(last.weight, std=0.05)
    if reads in ("told_specialist", "told_boundary"):
        for boundary in (False, True)[: 1 + (reads == "told_boundary")]:
            specialist = ToldCorrection(20, 16, boundary=boundary)
            for parameter in specialist.net.parameters():
                torch.nn.init.normal_(parameter, std=0.15)
            model.attach_told(specialist)
    if blend is not None:
        model.set_blend_weights(blend)
    model.set_sigma_told(0.6)
    return model.eval()


def told_boundaries(count: int, seed: int) -> torch.Tensor:
    """(count, 1) boundary shares as callers tell them: in 0 … 1, every other one unknown (−1)."""
    shares = torch.rand(count, 1, generator=torch.Generator().manual_seed(seed + 1000))
    shares[1::2] = -1.0
    return shares


def told(model: UnionOperator, count: int, seed: int) -> tuple[torch.Tensor | None, torch.Tensor | None]:
    """What a test tells ``model`` of its pairs: :func:`told_overlaps` if it reads them, and
    :func:`told_boundaries` if it reads those too."""
    overlap = told_overlaps(count, seed) if model.config.overlap_hint else None
    return overlap, told_boundaries(count, seed) if model.reads_boundary else None
