"""``app.contract.union_feeds``: the one place a union graph's inputs are made, whatever it reads."""

from pathlib import Path

import numpy as np
import onnxruntime as ort
import pytest

from app.contract import (
    UNION_BOUNDARY_INPUT,
    UNION_INPUTS,
    UNION_OVERLAP_INPUT,
    UNKNOWN_BOUNDARY,
    UNKNOWN_OVERLAP,
    union_feeds,
)
from app.inference.models import graph_inputs

MODELS = Path(__file__).resolve().parents[2] / "models"
A, B = np.array([[1.0, 2.0], [3.0, 4.0]]), np.array([[5.0, 6.0], [7.0, 8.0]])
EVERYTHING = frozenset({*UNION_INPUTS, UNION_OVERLAP_INPUT, UNION_BOUNDARY_INPUT})


def test_what_a_graph_reads_but_is_not_told_is_fed_unknown():
    feeds = union_feeds(EVERYTHING, A, B, overlap=np.array([0.25, 1.0]))
    assert feeds[UNION_INPUTS[0]].dtype == np.float32 and feeds[UNION_INPUTS[0]].tolist() == A.tolist()
    assert feeds[UNION_OVERLAP_INPUT].tolist() == [[0.25], [1.0]]
    assert feeds[UNION_BOUNDARY_INPUT].tolist() == [[UNKNOWN_BOUNDARY], [UNKNOWN_BOUNDARY]]
    untold = union_feeds(EVERYTHING, A, B)
    assert untold[UNION_OVERLAP_INPUT].tolist() == [[UNKNOWN_OVERLAP], [UNKNOWN_OVERLAP]]


def test_a_graph_that_reads_no_hint_gets_none_and_a_hint_it_cannot_read_is_refused():
    assert set(union_feeds(frozenset(UNION_INPUTS), A, B)) == set(UNION_INPUTS)
    with pytest.raises(ValueError, match="overlap"):
        union_feeds(frozenset(UNION_INPUTS), A, B, overlap=np.array([0.5, 0.5]))
    with pytest.raises(ValueError, match="boundary"):
        union_feeds(EVERYTHING - {UNION_BOUNDARY_INPUT}, A, B, np.array([0.5, 0.5]), np.array([0.1, 0.1]))


def test_the_served_graph_runs_on_what_union_feeds_makes_and_unknown_is_told_nothing():
    """Told nothing, told unknown explicitly and fed unknown by default are one answer."""
    graph = ort.InferenceSession(str(MODELS / "union.onnx"), providers=["CPUExecutionProvider"])
    reads = graph_inputs(graph)
    bodies = np.load(MODELS / "shapes.npz")["spectra"][:4]
    a, b = 1.5 * bodies[:2], 2.0 * bodies[2:4]
    default = graph.run(None, union_feeds(reads, a, b))
    explicit = graph.run(None, union_feeds(reads, a, b, np.full(2, UNKNOWN_OVERLAP), np.full(2, UNKNOWN_BOUNDARY)))
    told = graph.run(None, union_feeds(reads, a, b, np.array([0.0, 0.0])))
    assert all(np.array_equal(d, e) for d, e in zip(default, explicit, strict=True))
    assert not np.allclose(default[0], told[0])
