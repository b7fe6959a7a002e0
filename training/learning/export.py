"""ONNX export of the trained models, with the parity checks the service relies on.

Both graphs have a dynamic batch dimension and a fixed opset, and the input and output names
of :mod:`app.contract`, by which the service (onnxruntime, no torch) feeds and reads them.
The exporter records on every node the Python stack that made it (file paths and line
numbers): those are dropped, so that a graph's bytes change only when what it computes does,
and no path of the machine that trained it ships with it.
"""

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch
from onnx import numpy_helper

from app.contract import (
    LOCALIZER_INPUTS,
    LOCALIZER_OUTPUTS,
    RECONSTRUCTION_INPUTS,
    RECONSTRUCTION_OUTPUTS,
    UNION_BOUNDARY_INPUT,
    UNION_INPUTS,
    UNION_OUTPUTS,
    UNION_OVERLAP_INPUT,
    UNKNOWN_BOUNDARY,
    UNKNOWN_OVERLAP,
    union_feeds,
)
from app.inference.models import graph_inputs
from training.learning.localizer_net import Localizer
from training.learning.union_net import UnionOperator
from training.reconstruction.decoder import SpectrumDecoder

OPSET = 23  # ONNX's own Attention operator (union_net.EncoderLayer); Gelu one node since 20
SOURCE_METADATA = "pkg.torch.onnx.stack_trace"  # per node: where in our Python it was traced


def _export(
    model: torch.nn.Module,
    example: tuple[torch.Tensor, ...],
    path: Path,
    inputs,
    outputs,
    dynamic_shapes: tuple[dict, ...] | None = None,
) -> None:
    """Export with every input's first axis the batch, unless ``dynamic_shapes`` says otherwise."""
    model = model.cpu().eval()
    path.parent.mkdir(parents=True, exist_ok=True)
    if dynamic_shapes is None:
        batch = torch.export.Dim("batch", min=1, max=65536)
        dynamic_shapes = tuple({0: batch} for _ in example)
    torch.onnx.export(
        model,
        example,
        str(path),
        input_names=list(inputs),
        output_names=list(outputs),
        opset_version=OPSET,
        dynamic_shapes=dynamic_shapes,
        external_data=False,
        dynamo=True,
        verbose=False,
    )
    graph = onnx.load(str(path))
    for node in [*graph.graph.node, *(n for function in graph.functions for n in function.node)]:
        kept = [entry for entry in node.metadata_props if entry.key != SOURCE_METADATA]
        del node.metadata_props[:]
        node.metadata_props.extend(kept)
    onnx.save(graph, str(path))


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
        _export(_WithOverlap(model), (example, example * 1.5, *told), path, inputs, UNION_OUTPUTS)
    elif model.config.overlap_hint:
        overlap = torch.tensor([[0.5], [UNKNOWN_OVERLAP]])
        inputs = (*UNION_INPUTS, UNION_OVERLAP_INPUT)
        _export(_WithOverlap(model), (example, example * 1.5, overlap), path, inputs, UNION_OUTPUTS)
    else:
        _export(model, (example, example * 1.5), path, UNION_INPUTS, UNION_OUTPUTS)


def export_localizer(model: Localizer, path: Path) -> None:
    example = torch.linspace(1, 60, model.config.k).repeat(2, 1)
    _export(model, (example,), path, LOCALIZER_INPUTS, LOCALIZER_OUTPUTS)


def export_decoder(model: SpectrumDecoder, path: Path) -> None:
    example = torch.linspace(0, 60, model.config.k).repeat(2, 1)
    _export(model, (example, 0.1 * example), path, RECONSTRUCTION_INPUTS, RECONSTRUCTION_OUTPUTS)


def decoder_basis(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(3V,) mean body and (C, 3V) components times their spread, read back from an exported decoder
    graph (:class:`SpectrumDecoder`'s buffers): the shape basis its whitened coefficients multiply,
    for benchmarks that work in it."""
    arrays = {tensor.name: numpy_helper.to_array(tensor) for tensor in onnx.load(str(path)).graph.initializer}
    return arrays["mean"].astype(np.float64), arrays["components"].astype(np.float64)


def session(path: Path) -> ort.InferenceSession:
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


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
    return max(_relative(g, e.numpy()) for g, e in zip(got, expected, strict=True))


def localizer_parity(model: Localizer, path: Path, spectra: np.ndarray) -> float:
    return _graph_parity(model, path, LOCALIZER_INPUTS, (spectra,))


def decoder_parity(model: SpectrumDecoder, path: Path, spectra: np.ndarray, sigma: np.ndarray) -> float:
    return _graph_parity(model, path, RECONSTRUCTION_INPUTS, (spectra, sigma))


def _graph_parity(model: torch.nn.Module, path: Path, names: tuple[str, ...], arrays: tuple[np.ndarray, ...]) -> float:
    """Largest relative difference between onnxruntime and PyTorch for a graph with one output,
    on these inputs (in the graph's input order)."""
    inputs = [x.astype(np.float32) for x in arrays]
    with torch.no_grad():
        expected = model.eval()(*(torch.as_tensor(x) for x in inputs)).numpy()
    (got,) = session(path).run(None, dict(zip(names, inputs, strict=True)))
    return _relative(got, expected)


def _relative(got: np.ndarray, expected: np.ndarray) -> float:
    """Largest difference relative to the output's own scale (probabilities near 0 have no
    meaningful elementwise relative error; eigenvalues and σ are compared the same way)."""
    return float(np.max(np.abs(got - expected)) / max(float(np.max(np.abs(expected))), 1e-12))
