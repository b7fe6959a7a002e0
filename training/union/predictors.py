"""The models as the evaluation reads them: the PyTorch modules of a finished run, or the ONNX
graphs of a models folder, each as plain functions of numpy spectra, so that one evaluation
scores either (and a committed model on a data set it was not evaluated on)."""

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import onnxruntime as ort

from app.contract import LOCALIZER_FILE, LOCALIZER_INPUTS, UNION_FILE, union_feeds
from app.inference import graph_inputs, reads_boundary, reads_overlap
from training.localizer.masks import SERVED_LOCALIZER
from training.localizer.net import Localizer
from training.localizer.train import probabilities
from training.union.net import UnionOperator
from training.union.predict import predict

UnionPredictor = Callable[[np.ndarray, np.ndarray], tuple[np.ndarray, np.ndarray]]  # (a, b) → (union, σ)


@dataclass(frozen=True)
class ToldPredictor:
    """(a, b, overlap[, boundary]) → (union, σ): an operator told each pair's overlap, and its
    boundary share where it reads one (``reads_boundary``)."""

    predict: Callable[[np.ndarray, np.ndarray, np.ndarray, np.ndarray | None], tuple[np.ndarray, np.ndarray]]
    reads_boundary: bool

    def __call__(
        self, a: np.ndarray, b: np.ndarray, overlap: np.ndarray, boundary: np.ndarray | None = None
    ) -> tuple[np.ndarray, np.ndarray]:
        if boundary is not None and not self.reads_boundary:
            raise ValueError("this operator does not read the boundary share")
        return self.predict(a, b, overlap, boundary)


RegionPredictor = Callable[[np.ndarray], np.ndarray]  # spectra → (m, n) each template vertex's probability


def trained_predictors(
    union: UnionOperator, localizers: dict[str, Localizer]
) -> tuple[UnionPredictor, dict[str, RegionPredictor]]:
    """The PyTorch models as the evaluator's predictors."""
    regions = {name: (lambda spectra, model=model: probabilities(model, spectra)) for name, model in localizers.items()}
    return (lambda a, b: predict(union, a, b)), regions


def told_predictor(union: UnionOperator) -> ToldPredictor | None:
    """The operator told each pair's overlap, or None for one that does not read it."""
    if not union.config.overlap_hint:
        return None
    told = lambda a, b, overlap, boundary: predict(union, a, b, overlap=overlap, boundary=boundary)  # noqa: E731
    return ToldPredictor(told, union.reads_boundary)


def served_predictors(models: Path, batch: int = 1024) -> tuple[UnionPredictor, dict[str, RegionPredictor]]:
    """The exported ONNX graphs of a models folder as the evaluator's predictors: how a committed
    model (this one or an earlier one) scores on a data set it was not evaluated on."""
    from training.common.onnx_export import session

    union_graph, localizer_graph = session(models / UNION_FILE), session(models / LOCALIZER_FILE)

    def union(a: np.ndarray, b: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        return _run_union(union_graph, a, b, None, batch)  # told nothing

    def region(spectra: np.ndarray) -> np.ndarray:
        return localizer_graph.run(None, {LOCALIZER_INPUTS[0]: spectra.astype(np.float32)})[0]

    return union, {SERVED_LOCALIZER: region}


def served_told_predictor(models: Path, batch: int = 1024) -> ToldPredictor | None:
    """The exported union graph told each pair's overlap, or None for a graph without that input."""
    from training.common.onnx_export import session

    graph = session(models / UNION_FILE)
    if not reads_overlap(graph):
        return None
    told = lambda a, b, overlap, boundary: _run_union(graph, a, b, overlap, batch, boundary)  # noqa: E731
    return ToldPredictor(told, reads_boundary(graph))


def _run_union(
    graph: ort.InferenceSession,
    a: np.ndarray,
    b: np.ndarray,
    overlap: np.ndarray | None,
    batch: int,
    boundary: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(union, σ) of an onnxruntime union graph, in batches; told nothing of what is None."""
    reads, outputs = graph_inputs(graph), []
    for start in range(0, len(a), batch):
        window = slice(start, start + batch)
        told, edge = (None if x is None else x[window] for x in (overlap, boundary))
        outputs.append(graph.run(None, union_feeds(reads, a[window], b[window], told, edge)))
    return np.concatenate([o[0] for o in outputs]), np.concatenate([o[1] for o in outputs])
