"""ONNX export of the union operator and the localizer, with the parity checks the service
relies on (the export machinery: :mod:`training.common.onnx_export`). Both graphs have a dynamic batch
dimension."""

from pathlib import Path

import numpy as np
import torch

from app.contract import (
    LOCALIZER_INPUTS,
    LOCALIZER_OUTPUTS,
    UNION_BOUNDARY_INPUT,
    UNION_INPUTS,
    UNION_OUTPUTS,
    UNION_OVERLAP_INPUT,
    UNKNOWN_BOUNDARY,
    UNKNOWN_OVERLAP,
    union_feeds,
)
from app.inference import graph_inputs
from training.common.onnx_export import export_graph, graph_parity, relative_difference, session
from training.localizer.net import Localizer
from training.union.net import UnionOperator


class _WithOverlap(torch.nn.Module):
    """The operator as served when it reads the overlap: (a, b, overlap[, boundary]) → (union, σ)."""

    def __init__(self, model: UnionOperator) -> None:
        super().__init__()
        self.model = model

    def forward(
        self, a: torch.Tensor, b: torch.Tensor, overlap: torch.Tensor, boundary: torch.Tensor | None = None
    ) -> tuple[torch.Tensor, torch.Tensor]:
        return self.model(a, b, None, overlap, boundary)


def export_union(model: UnionOperator, path: Path) -> None:
    """The graph reads ``UNION_OVERLAP_INPUT`` too when the operator was trained to, and
    ``UNION_BOUNDARY_INPUT`` when its told specialist reads the boundary share."""
    k = model.config.k
    example = torch.linspace(1, 60, k).repeat(2, 1)
    if model.reads_boundary:
        told = torch.tensor([[0.5], [UNKNOWN_OVERLAP]]), torch.tensor([[0.6], [UNKNOWN_BOUNDARY]])
        inputs = (*UNION_INPUTS, UNION_OVERLAP_INPUT, UNION_BOUNDARY_INPUT)
        export_graph(_WithOverlap(model), (example, example * 1.5, *told), path, inputs, UNION_OUTPUTS)
    elif model.config.overlap_hint:
        overlap = torch.tensor([[0.5], [UNKNOWN_OVERLAP]])
        inputs = (*UNION_INPUTS, UNION_OVERLAP_INPUT)
        export_graph(_WithOverlap(model), (example, example * 1.5, overlap), path, inputs, UNION_OUTPUTS)
    else:
        export_graph(model, (example, example * 1.5), path, UNION_INPUTS, UNION_OUTPUTS)


def export_localizer(model: Localizer, path: Path) -> None:
    example = torch.linspace(1, 60, model.config.k).repeat(2, 1)
    export_graph(model, (example,), path, LOCALIZER_INPUTS, LOCALIZER_OUTPUTS)


def union_parity(
    model: UnionOperator,
    path: Path,
    a: np.ndarray,
    b: np.ndarray,
    overlap: np.ndarray | None = None,
    boundary: np.ndarray | None = None,
) -> float:
    """Largest relative difference between onnxruntime and PyTorch on these operands (and
    overlaps and boundary shares, for an operator that reads them; told nothing of what is
    None, on both sides)."""
    told, edge = (
        None if x is None else torch.as_tensor(x, dtype=torch.float32).reshape(-1, 1) for x in (overlap, boundary)
    )
    with torch.no_grad():
        expected = model.eval()(torch.as_tensor(a), torch.as_tensor(b), None, told, edge)
    graph = session(path)
    got = graph.run(None, union_feeds(graph_inputs(graph), a, b, overlap, boundary))
    return max(relative_difference(g, e.numpy()) for g, e in zip(got, expected, strict=True))


def localizer_parity(model: Localizer, path: Path, spectra: np.ndarray) -> float:
    return graph_parity(model, path, LOCALIZER_INPUTS, (spectra,))
