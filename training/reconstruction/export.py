"""ONNX export of the shape decoder, its parity, and its shape basis read back from the graph
(the export machinery: :mod:`training.common.onnx_export`)."""

from pathlib import Path

import numpy as np
import onnx
import torch
from onnx import numpy_helper

from app.contract import RECONSTRUCTION_INPUTS, RECONSTRUCTION_OUTPUTS
from training.common.onnx_export import export_graph, graph_parity
from training.reconstruction.decoder import SpectrumDecoder


def export_decoder(model: SpectrumDecoder, path: Path) -> None:
    example = torch.linspace(0, 60, model.config.k).repeat(2, 1)
    export_graph(model, (example, 0.1 * example), path, RECONSTRUCTION_INPUTS, RECONSTRUCTION_OUTPUTS)


def decoder_basis(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(3V,) mean body and (C, 3V) components times their spread, read back from an exported decoder
    graph (:class:`SpectrumDecoder`'s buffers): the shape basis its whitened coefficients multiply,
    for benchmarks that work in it."""
    arrays = {tensor.name: numpy_helper.to_array(tensor) for tensor in onnx.load(str(path)).graph.initializer}
    return arrays["mean"].astype(np.float64), arrays["components"].astype(np.float64)


def decoder_parity(model: SpectrumDecoder, path: Path, spectra: np.ndarray, sigma: np.ndarray) -> float:
    return graph_parity(model, path, RECONSTRUCTION_INPUTS, (spectra, sigma))
