"""The exported union operator picks the same training pairs as PyTorch, even among near-ties."""

import numpy as np
import pytest

torch = pytest.importorskip("torch")
pytest.importorskip("onnxscript")

from training.union.config import UnionConfig  # noqa: E402
from training.union.corrections import ToldCorrection  # noqa: E402
from training.union.export import export_union, session  # noqa: E402
from training.union.memory import UnionMemory  # noqa: E402
from training.union.net import UnionOperator  # noqa: E402


def test_onnx_and_pytorch_retrieve_the_same_pairs_among_near_ties(tmp_path):
    """A memory of pairs that differ by ~0.1 % (the nearest gaps far below the float32 rounding
    of a distance), with very different unions: a neighbour picked differently shows at once."""
    rng = np.random.default_rng(0)
    base_a, base_b = (np.cumsum(rng.uniform(1, 40, (1, 20)), axis=1) for _ in range(2))
    stored = 4000
    a = base_a * (1 + 1e-3 * rng.standard_normal((stored, 20)))
    b = base_b * (1 + 1e-3 * rng.standard_normal((stored, 20)))
    union = np.sort(rng.uniform(0.5, 80, (stored, 20)), axis=1)
    model = UnionOperator(UnionConfig(), UnionMemory(a, b, union)).eval()
    queries = 500
    qa = (base_a * (1 + 1e-3 * rng.standard_normal((queries, 20)))).astype(np.float32)
    qb = (base_b * (1 + 1e-3 * rng.standard_normal((queries, 20)))).astype(np.float32)
    export_union(model, tmp_path / "union.onnx")
    got, _ = session(tmp_path / "union.onnx").run(None, {"spectrum_a": qa, "spectrum_b": qb})
    with torch.no_grad():
        expected = model(torch.as_tensor(qa), torch.as_tensor(qb))[0].numpy()
    assert np.abs(got - expected).max() <= 1e-4 * np.abs(expected).max()


def test_onnx_and_pytorch_break_exact_ties_alike(tmp_path):
    """Pairs stored twice with the very same spectra but different unions (a part with itself and
    its re-scan in the same pose are such a pair): both runtimes must take the same one. Without
    the tie-break, torch's and onnxruntime's top-k disagreed on one of 9 427 real test rows."""
    rng = np.random.default_rng(1)
    a, b = (np.cumsum(rng.uniform(1, 40, (200, 20)), axis=1) for _ in range(2))
    union = np.sort(rng.uniform(0.5, 80, (400, 20)), axis=1)
    model = UnionOperator(UnionConfig(), UnionMemory(np.tile(a, (2, 1)), np.tile(b, (2, 1)), union)).eval()
    qa, qb = a.astype(np.float32), b.astype(np.float32)
    export_union(model, tmp_path / "union.onnx")
    got = session(tmp_path / "union.onnx").run(None, {"spectrum_a": qa, "spectrum_b": qb})
    with torch.no_grad():
        expected = [x.numpy() for x in model(torch.as_tensor(qa), torch.as_tensor(qb))]
    for g, e in zip(got, expected, strict=True):
        assert np.abs(g - e).max() <= 1e-4 * np.abs(e).max()


@pytest.mark.parametrize("specialist", [None, "share", "boundary"])
def test_an_operator_that_reads_the_overlap_exports_it_as_an_input(tmp_path, specialist):
    """The graph of an operator trained with the overlap hint takes ``overlap`` (batch, 1), told or
    unknown per row, and answers as PyTorch does (random correction weights, so the hint matters;
    with ``specialist``, a told specialist of random weights answers the told rows, and with
    "boundary" a second one those told the boundary share too, an input of its own); one trained
    without it has no such input."""
    # The weights are random: seeded, so that whether the hint moves the union does not depend on
    # which tests ran before (some draws put every proposal far above the minimum, where the
    # decrease is exactly 0 whatever the correction reads).
    torch.manual_seed(0)
    rng = np.random.default_rng(2)
    a, b = (np.cumsum(rng.uniform(1, 40, (300, 20)), axis=1) for _ in range(2))
    union = np.minimum(a, b) * 0.7
    for hint in (False, True):
        model = UnionOperator(UnionConfig(disjoint_prior=True, overlap_hint=hint), UnionMemory(a, b, union))
        torch.nn.init.normal_(model.correction.rho.weight, std=0.05)
        model.set_sigma_told(0.5)
        if hint and specialist:
            model.attach_told(ToldCorrection(20, 32))
        if hint and specialist == "boundary":
            model.attach_told(ToldCorrection(20, 32, boundary=True))
        export_union(model.eval(), tmp_path / f"union-{hint}.onnx")
        graph = session(tmp_path / f"union-{hint}.onnx")
        inputs = {node.name for node in graph.get_inputs()}
        assert ("overlap" in inputs) == hint and ("boundary" in inputs) == (hint and specialist == "boundary")
    qa, qb = a[:64].astype(np.float32), b[::-1][:64].copy().astype(np.float32)
    overlap = rng.uniform(0, 1, (64, 1)).astype(np.float32)
    overlap[::4] = -1.0
    feeds = {"spectrum_a": qa, "spectrum_b": qb, "overlap": overlap}
    boundary = None
    if specialist == "boundary":
        boundary = rng.uniform(0, 1, (64, 1)).astype(np.float32)
        boundary[1::3] = -1.0
        feeds["boundary"] = boundary
    got = graph.run(None, feeds)
    with torch.no_grad():
        told = torch.as_tensor(overlap), None if boundary is None else torch.as_tensor(boundary)
        expected = [x.numpy() for x in model(torch.as_tensor(qa), torch.as_tensor(qb), None, *told)]
        nothing = model(torch.as_tensor(qa), torch.as_tensor(qb))[0].numpy()
    for g, e in zip(got, expected, strict=True):
        assert np.abs(g - e).max() <= 1e-4 * np.abs(e).max()
    assert np.abs(expected[0] - nothing).max() > 1e-3 * np.abs(nothing).max()  # the hint changed the answer
