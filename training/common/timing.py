"""Timing several runs fairly on a machine whose speed drifts."""

import statistics
import time
from collections.abc import Callable


def interleaved_ms(runs: dict[str, Callable[[], object]], repeats: int) -> dict[str, float]:
    """Median milliseconds of each run, the runs taking turns within every repeat, so that a
    drift in the machine's speed (this VM's varies by ~30 % over minutes) weighs on all alike."""
    times: dict[str, list[float]] = {name: [] for name in runs}
    for _ in range(repeats):
        for name, run in runs.items():
            started = time.perf_counter()
            run()
            times[name].append(time.perf_counter() - started)
    return {name: 1e3 * statistics.median(values) for name, values in times.items()}
