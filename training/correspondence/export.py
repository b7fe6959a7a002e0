"""ONNX export of the correspondence network, and its parity with PyTorch.

The graph takes one part (the contract's inputs, :data:`app.contract.CORRESPONDENCE_INPUTS`)
with its vertex count, stencil width and basis size all dynamic; it takes the gradient of the
basis once, by gather (the stencil's form the service feeds), and each block's gradients from it.
"""

import copy
from pathlib import Path

import numpy as np
import torch

from app.contract import CORRESPONDENCE_INPUTS, CORRESPONDENCE_OUTPUTS
from training.common.onnx_export import export_graph, relative_difference, session
from training.correspondence.net import CorrespondenceNet, stencil_matrices


def export_correspondence(model: CorrespondenceNet, example: dict[str, np.ndarray], path: Path) -> None:
    """Export ``model`` traced on one part's inputs (``example``, by contract name)."""
    vertices = torch.export.Dim("vertices", min=8, max=1_000_000)
    width = torch.export.Dim("stencil", min=1, max=64)
    k = torch.export.Dim("basis", min=2, max=512)
    shapes = (
        {0: vertices},
        {0: vertices},
        {0: vertices, 1: k},
        {0: k},
        {0: vertices, 1: width},
        {0: vertices, 1: width},
    )
    inputs = tuple(torch.as_tensor(example[name]) for name in CORRESPONDENCE_INPUTS)
    export_graph(model, inputs, path, CORRESPONDENCE_INPUTS, CORRESPONDENCE_OUTPUTS, shapes)


def correspondence_parity(model: CorrespondenceNet, path: Path, parts: list[dict[str, np.ndarray]]) -> float:
    """Largest difference of the place (relative to the template's extent) and the confidence
    between onnxruntime and the network's exact answer over ``parts``: the training path (sparse
    stencil) in float64. Against the training path in float32 the difference is mostly that
    path's own rounding (on the test's network: 2.1e-4 from float64 where the graph is 1.3e-4)."""
    graph = session(path)
    exact = copy.deepcopy(model).double().eval()
    worst = 0.0
    for part in parts:
        got = graph.run(None, {name: part[name] for name in CORRESPONDENCE_INPUTS})
        expected = training_path(exact, part)
        worst = max(worst, *(relative_difference(g, e) for g, e in zip(got, expected, strict=True)))
    return worst


def training_path(model: CorrespondenceNet, part: dict[str, np.ndarray]) -> tuple[np.ndarray, np.ndarray]:
    """The network's (place, confidence) of one part by its training path (sparse stencil), its
    inputs cast to the network's own precision (float32 as trained, float64 for the exact answer)."""
    dtype = next(model.parameters()).dtype
    inputs = [torch.as_tensor(part[name]) for name in CORRESPONDENCE_INPUTS]
    inputs = [x.to(dtype) if x.is_floating_point() else x for x in inputs]
    with torch.no_grad():
        return tuple(x.numpy() for x in model.place(model.heads(*inputs, stencil_matrices(inputs[4], inputs[5]))))
