"""Inference speed and size of the served ONNX models, as the service runs them.

Run: ``python benchmarks/bench_models.py [--models models] [--against OTHER] [--rounds 3]``
(onnxruntime only, no torch). Prints the file sizes and the median-of-N milliseconds of one
``run`` of the union operator (its memory search included) and of the localizer, at batch 1 (one
request) and batch 256 (a client posting many spectra), with one intra-op thread as the
service's sessions use, told nothing (as most pairs arrive). Operands are the seed database's
complete-body spectra, scaled up as parts are (a part's eigenvalues lie above its body's).
``--against`` times another models folder's union graph on the same operands in alternating
rounds: this VM's speed drifts by tens of per cent over minutes, so two graphs timed one after
the other do not compare.
"""

import argparse
import statistics
import time
from pathlib import Path

import numpy as np
import onnxruntime as ort

from app.contract import union_feeds
from app.inference.models import graph_inputs

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


def operands(bodies: np.ndarray, batch: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    rows = rng.integers(len(bodies), size=(2, batch))
    a = np.sort(bodies[rows[0]] * rng.uniform(1.2, 3.0, (batch, 1)), axis=1).astype(np.float32)
    b = np.sort(bodies[rows[1]] * rng.uniform(1.2, 3.0, (batch, 1)), axis=1).astype(np.float32)
    return a, b


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--models", type=Path, default=Path("models"))
    parser.add_argument("--against", type=Path, help="another models folder, its union graph timed in turns")
    parser.add_argument("--rounds", type=int, default=1)
    args = parser.parse_args()
    bodies = np.load(args.models / "shapes.npz")["spectra"].astype(np.float32)
    rng = np.random.default_rng(0)
    folders = [args.models] + ([args.against] if args.against else [])
    unions = {folder: session(folder / "union.onnx") for folder in folders}
    localizer = session(args.models / "localizer.onnx")
    for folder in folders:
        for name in ("union.onnx", "localizer.onnx"):
            print(f"{folder / name!s:32s} {(folder / name).stat().st_size / 2**20:6.2f} MiB")
    for batch in (1, 256):
        a, b = operands(bodies, batch, rng)
        localizer_ms = median_ms(lambda a=a: localizer.run(None, {"spectrum": a}))
        print(f"batch {batch:4d}: localizer {localizer_ms:8.2f} ms")
        for round_ in range(args.rounds):
            for folder, union in unions.items():
                feeds = union_feeds(graph_inputs(union), a, b)
                union_ms = median_ms(lambda union=union, feeds=feeds: union.run(None, feeds))
                print(f"batch {batch:4d}, round {round_ + 1}: union {union_ms:8.2f} ms   ({folder})")


if __name__ == "__main__":
    main()
