"""Speed of the data build's spectra stage, measured on a sample of a built data set's own tasks.

Run: ``python -m benchmarks.bench_build_spectra --data data/standard --tasks 2000``
(needs a built data set: ``make dataset``). A uniform sample of the build's distinct
(shape, mask, variant) tasks goes through the build's own worker function on the build's own
process pool, chunked as the build chunks them, so the wall time per task is what the full
stage pays per task on this machine; the stage time is projected from it. The sample's
spectra are compared with the data set's stored ones, so a speed-up that changes a spectrum
shows here.
"""

import json
import time

import numpy as np

from benchmarks.arguments import benchmark_parser
from training.data.workers import chunks, run_tasks, solve_chunk


def main() -> None:
    parser = benchmark_parser(__doc__)
    parser.add_argument("--tasks", type=int, default=2000)
    parser.add_argument("--workers", type=int, default=2)
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args()

    preset = json.loads((args.data / "manifest.json").read_text())["preset"]
    arrays = np.load(args.data / "dataset.npz")
    tasks = np.stack([arrays["spectrum_shape"], arrays["spectrum_mask"]], axis=1)
    variants, stored = arrays["spectrum_variant"], arrays["spectra"]
    sample = np.sort(np.random.default_rng(args.seed).choice(len(tasks), size=args.tasks, replace=False))
    batches = list(chunks(sample, preset["chunk"]))
    paths = (str(args.data / "template"), str(args.data / "work/shapes.npy"), str(args.data / "work/masks.npy"))
    arguments = [(*paths, tasks[c], variants[c], preset["k"]) for c in batches]
    results: dict[int, np.ndarray] = {}
    started = time.perf_counter()
    run_tasks(solve_chunk, arguments, results.__setitem__, None, args.workers, "spectra")
    seconds = time.perf_counter() - started
    computed = np.concatenate([results[i] for i in range(len(batches))])
    expected = stored[sample]
    # Relative to each eigenvalue, or to 1e-9 of the spectrum's top one for the λ₁ = 0 of closed
    # shapes (a numerical zero of ~1e-13 is noise, not an eigenvalue to compare).
    floor = 1e-9 * np.abs(expected[:, -1:])
    deviation = np.nanmax(np.abs(computed - expected) / np.maximum(np.abs(expected), floor))
    per_task = seconds / args.tasks
    print(f"{args.tasks} of {len(tasks)} tasks on {args.workers} workers: {seconds:.1f} s wall")
    print(f"{1e3 * per_task:.1f} ms wall per task, {1e3 * per_task * args.workers:.1f} worker-ms per task")
    print(f"projected spectra stage: {per_task * len(tasks) / 60:.1f} min")
    print(f"largest relative deviation from the stored spectra: {deviation:.1e}")


if __name__ == "__main__":
    main()
