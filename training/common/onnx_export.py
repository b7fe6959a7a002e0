"""ONNX export and parity, shared by every trained model (union operator, localizer, shape
decoder, correspondence network).

Every graph has a fixed opset and the input and output names of :mod:`app.contract`, by which
the service (onnxruntime, no torch) feeds and reads it. The exporter records on every node the
Python stack that made it (file paths and line numbers): those are dropped, so that a graph's
bytes change only when what it computes does, and no path of the machine that trained it ships
with it.
"""

from pathlib import Path

import numpy as np
import onnx
import onnxruntime as ort
import torch

OPSET = 23  # ONNX's own Attention operator (corrections.EncoderLayer); Gelu one node since 20
SOURCE_METADATA = "pkg.torch.onnx.stack_trace"  # per node: where in our Python it was traced


def export_graph(
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


def session(path: Path) -> ort.InferenceSession:
    return ort.InferenceSession(str(path), providers=["CPUExecutionProvider"])


def graph_parity(model: torch.nn.Module, path: Path, names: tuple[str, ...], arrays: tuple[np.ndarray, ...]) -> float:
    """Largest relative difference between onnxruntime and PyTorch for a graph with one output,
    on these inputs (in the graph's input order)."""
    inputs = [x.astype(np.float32) for x in arrays]
    with torch.no_grad():
        expected = model.eval()(*(torch.as_tensor(x) for x in inputs)).numpy()
    (got,) = session(path).run(None, dict(zip(names, inputs, strict=True)))
    return relative_difference(got, expected)


def relative_difference(got: np.ndarray, expected: np.ndarray) -> float:
    """Largest difference relative to the output's own scale (probabilities near 0 have no
    meaningful elementwise relative error; eigenvalues and σ are compared the same way)."""
    return float(np.max(np.abs(got - expected)) / max(float(np.max(np.abs(expected))), 1e-12))
