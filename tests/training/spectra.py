"""Random spectra for the models' tests: ascending, like eigenvalues, reproducible by seed."""

import torch

from training.union.memory import common_scale, relative_log


def spectra(count: int, seed: int) -> torch.Tensor:
    generator = torch.Generator().manual_seed(seed)
    return torch.cumsum(torch.rand(count, 20, generator=generator) * 40, dim=1)


def relative_logs(a: torch.Tensor, b: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
    scale = common_scale(a, b)
    return relative_log(a, scale), relative_log(b, scale)
