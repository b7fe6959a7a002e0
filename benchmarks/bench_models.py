"""Inference speed and size of the served ONNX models, as the service runs them.

Run: ``python benchmarks/bench_models.py [--models models]`` (onnxruntime only, no torch).
Prints the file sizes and the median-of-N milliseconds of one ``run`` of the union operator
(its memory search included) and of the localizer, at batch 1 (one request) and batch 256
(a client posting many spectra), with one intra-op thread as the service's sessions use.
Operands are the seed database's complete-body spectra, scaled up as parts are (a part's
eigenvalues lie above its body's).
"""

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

from app.contract import UNKNOWN_BOUNDARY, UNKNOWN_OVERLAP, union_feeds
from app.inference.models import reads_boundary, reads_overlap

REPEATS = 50


def session(path: Path) -> ort.InferenceSession:
    options = ort.SessionOptions()
    options.intra_op_num_threads = 1
    return ort.InferenceSession(str(path), options, providers=["CPUExecutionProvider"])


def median_ms(run, repeats: int = REPEATS) -> float:
    run()  # warm-up: the first run allocates
    times = []
    for _ in range(repeats):
        started = time.perf_counter()
        run()
        times.append(1e3 * (time.perf_counter() - started))
    return statistics.median(times)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=Path("models"))
    args = parser.parse_args()
    bodies = np.load(args.models / "shapes.npz")["spectra"].astype(np.float32)
    rng = np.random.default_rng(0)
    union, localizer = session(args.models / "union.onnx"), session(args.models / "localizer.onnx")
    told_unknown, boundary_unknown = reads_overlap(union), reads_boundary(union)
    for name in ("union.onnx", "localizer.onnx"):
        print(f"{name:16s} {(args.models / name).stat().st_size / 2**20:6.2f} MiB")
    for batch in (1, 256):
        rows = rng.integers(len(bodies), size=(2, batch))
        a = np.sort(bodies[rows[0]] * rng.uniform(1.2, 3.0, (batch, 1)), axis=1).astype(np.float32)
        b = np.sort(bodies[rows[1]] * rng.uniform(1.2, 3.0, (batch, 1)), axis=1).astype(np.float32)
        told = np.full(batch, UNKNOWN_OVERLAP) if told_unknown else None  # as the service feeds it, untold
        edge = np.full(batch, UNKNOWN_BOUNDARY) if boundary_unknown else None
        feeds = union_feeds(a, b, told, edge)
        union_ms = median_ms(lambda feeds=feeds: union.run(None, feeds))
        localizer_ms = median_ms(lambda a=a: localizer.run(None, {"spectrum": a}))
        print(f"batch {batch:4d}: union {union_ms:8.2f} ms   localizer {localizer_ms:8.2f} ms")


if __name__ == "__main__":
    main()
