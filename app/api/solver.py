"""Eigen-solves of uploaded shapes in worker processes: bounded, stoppable, memory-capped.

A thread cannot be stopped, so a pathological upload solved in one would hold a slot (and
its memory) for as long as it liked. Here each solve runs in a pebble worker process with a
deadline: when it passes, pebble kills the worker and starts a fresh one, and the client
gets 422 ``solve-timeout``. Each worker's address space is capped (``RLIMIT_AS``), so an
upload whose factorization would not fit fails with 422 ``solve-memory-exceeded`` instead
of taking the host's memory. A worker that dies for any other reason (killed, crashed) is
replaced too; its request is answered 503 ``solver-crashed`` with ``Retry-After``.

``concurrency`` solves run at once and the rest wait for a slot; how many may wait is bounded
in front of the pool, per request, when its headers arrive (``app.api.admission``).
Workers start from a fork server that has already imported the geometry code, so replacing
one costs milliseconds, not the seconds of a fresh interpreter; that is also why each worker is
retired after ``tasks_per_worker`` solves (0: never): a worker's resident memory creeps up by
~15 MB per 300 solves (allocator fragmentation), and a fresh one starts from ~90 MB.
"""

import asyncio
import ctypes
import ctypes.util
import gc
import multiprocessing
import os
import resource
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any, TypeVar

import anyio
import numpy as np
from pebble import ProcessExpired, ProcessPool
from scipy.linalg import blas
from threadpoolctl import threadpool_limits

from app.api.metrics import SOLVES
from app.api.problems import ProblemError
from app.core.errors import InputError
from app.geometry.pipeline import Solved, SpectrumOptions, SpectrumReport, solve_bytes
from app.geometry.plausibility import placeable_size
from app.inference.correspondence import places_in_worker
from app.sessions.aligned import AlignedUnion
from app.sessions.fused import View
from app.sessions.seen import seen_in_worker
from app.sessions.solved import solved_union

RETRY_AFTER_SECONDS = 1  # a solve takes a fraction of a second: a place frees within one
_PRELOADED = ["app.geometry.pipeline", "app.inference.correspondence", "app.sessions.aligned"]
_CONTEXT = multiprocessing.get_context("forkserver")


def _init_worker(limit_bytes: int) -> None:
    """Worker initializer: cap the address space and keep BLAS to one thread.

    Allocations beyond the cap raise MemoryError in this worker only. One BLAS thread because
    the pool already runs a worker per core, and ARPACK's small dense products do not gain from
    threads anyway: a region's spectrum is faster on one thread than on OpenBLAS's default two,
    even alone on an idle machine, and workers each starting threads on shared cores made the
    batch build of the training data markedly slower.
    """
    threadpool_limits(limits=1)
    _map_blas_buffers()
    if limit_bytes > 0:
        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))


def _map_blas_buffers() -> None:
    """Make numpy's and SciPy's OpenBLAS map their work buffers now, below the cap.

    With one thread OpenBLAS maps its buffer (~64 MB) at the first BLAS call. Under a cap that
    a failed large solve left nearly full, that call cannot map it and OpenBLAS does not fail:
    the next small solve hung until its deadline (seen in the memory-cap test).
    """
    square = np.ones((64, 64))
    square @ square
    blas.dgemm(1.0, square, square)


Result = TypeVar("Result")


def _solve_task(
    data: bytes,
    file_type: str,
    options: SpectrumOptions,
    vectors: bool,
    footprint: bool,
    place_with: str | None = None,
    relaxed: bool = False,
) -> Solved:
    """The worker's task: a solve (:func:`_guarded`). With ``place_with`` (the correspondence
    graph's path) the part is placed here too (its places ``relaxed`` where asked), under the
    same cap and deadline, if no unit slip is plain in its size."""

    def work() -> Solved:
        placing = place_with is not None
        solved = solve_bytes(data, file_type, options, vectors=vectors, footprint=footprint, descriptors=placing)
        if not placing:
            return solved
        placeable_size(solved.report.area_m2, solved.report.scale_to_metres)
        return replace(solved, places=places_in_worker(place_with, solved.part, relaxed))

    return _guarded(work, "the solve needed more memory than a solver worker may use")


def _session_task(
    views: list[View], places: list[np.ndarray], registered: bool, k: int, seen_with: str | None
) -> np.ndarray | AlignedUnion | None:
    """The worker's task for a session's union (:func:`_guarded`,
    :func:`app.sessions.solved.solved_union`); ``seen_with``: a models directory whose body
    basis checks the fused boundary, or None."""
    seen = None if seen_with is None else seen_in_worker(seen_with)
    return _guarded(
        lambda: solved_union(views, places, registered, k, seen),
        "the session's fused views needed more memory than a solver worker may use",
    )


def _guarded(work: Callable[[], Result], failure: str) -> Result:
    """``work()`` in a worker: what it freed given back to the system when it ends, so a worker
    returns to about its idle size after every task, not after its largest (``python -m
    benchmarks.worker_memory``); a memory failure raised as :class:`SolveMemoryExceeded`
    (``failure``) without its traceback.

    A ``MemoryError``'s traceback holds the frames of the failed work, and with them every array
    it had built. pebble keeps a task's result (the exception) until the worker's next task has
    finished, so those arrays stayed mapped under the cap while the next upload was solved: a
    small patch after a failed large grid found ~8 MB of a 120 MB cap free and failed too, or
    not, by how far the large solve had got. The new error is raised once the handler has let
    the old one go (and the cycles it held are collected), so the worker is back at its idle size
    when it answers.
    """
    failed = False
    try:
        finished = work()
    except MemoryError:
        failed = True
    if failed:
        gc.collect()
    _return_freed_heap()
    if failed:
        raise SolveMemoryExceeded(failure)
    return finished


def _return_freed_heap() -> None:
    """Give the heap's free top back to the system (glibc ``malloc_trim``), where there is one.

    glibc serves mid-sized arrays from its heap once large ones have been freed, and keeps up to
    64 MB of freed heap mapped. Under the cap that is address space the next upload's arrays
    cannot have: after a large grid failed late in its solve the worker stayed 26–49 MB above its
    idle size (measured here and on CI) until trimmed.
    """
    libc_name = ctypes.util.find_library("c")
    if libc_name is None:
        return
    libc = ctypes.CDLL(libc_name)
    if hasattr(libc, "malloc_trim"):
        libc.malloc_trim(0)


class SolveTimeout(InputError):
    """The solve ran past the service's deadline and its worker was stopped."""

    slug = "solve-timeout"
    title = "Solve ran past its deadline"


class SolveMemoryExceeded(InputError):
    """The solve needed more memory than a solver worker may use."""

    slug = "solve-memory-exceeded"
    title = "Solve needs too much memory"


class SolverPool:
    """``concurrency`` worker processes, one solve each at a time."""

    def __init__(self, concurrency: int, timeout_s: float, memory_mb: int, tasks_per_worker: int = 0) -> None:
        self.limiter = anyio.CapacityLimiter(concurrency)
        self.timeout_s = timeout_s
        _CONTEXT.set_forkserver_preload(_PRELOADED)
        self._pool = ProcessPool(
            max_workers=concurrency,
            max_tasks=tasks_per_worker,
            context=_CONTEXT,
            initializer=_init_worker,
            initargs=(memory_mb * 1024 * 1024,),
        )

    async def start(self) -> None:
        """Start the workers now, so the first upload does not pay for the fork server."""
        await asyncio.wrap_future(self._pool.schedule(os.getpid))

    def close(self) -> None:
        """Stop the workers; in-flight requests were drained by the server before this."""
        self._pool.stop()
        self._pool.join()

    def worker_pids(self) -> list[int]:
        """The live workers' process ids (for fault tests and the fault benchmark)."""
        return [worker.pid for worker in self._pool._pool_manager.worker_manager.workers.values()]

    async def solve(self, data: bytes, file_type: str, options: SpectrumOptions) -> SpectrumReport:
        """The spectrum of one upload, or the error that says why not; see the module docstring."""
        return (await self.solve_with_functions(data, file_type, options, vectors=False)).report

    async def solve_with_functions(
        self,
        data: bytes,
        file_type: str,
        options: SpectrumOptions,
        *,
        vectors: bool = True,
        footprint: bool = False,
        place_with: Path | None = None,
        relaxed: bool = False,
    ) -> Solved:
        """The solve with (``vectors``) its eigenfunctions and their vertices' provenance,
        (``footprint``) where the shape lies (:mod:`app.geometry.overlap`) and, with ``place_with``
        (the correspondence graph's path), what that network reads of it
        (:mod:`app.geometry.descriptors`) and where it places it (``relaxed``: those places relaxed
        toward the part's edge lengths, :mod:`app.inference.relaxation`)."""
        async with self.limiter:
            graph = str(place_with) if place_with is not None else None
            task = (data, file_type, options, vectors, footprint, graph, relaxed)
            solved: Solved = await self._run(_solve_task, task, "the solve")
        SOLVES.observe((solved.report.assembly_ms + solved.report.solve_ms) / 1e3)
        return solved

    async def session_union(
        self, views: list[View], places: list[np.ndarray], registered: bool, k: int, seen_with: str | None
    ) -> np.ndarray | AlignedUnion | None:
        """The first ``k`` eigenvalues of a session's union solved on its views, in a worker under
        the same deadline and memory cap as an upload (:func:`_session_task`)."""
        async with self.limiter:
            task = (views, places, registered, k, seen_with)
            return await self._run(_session_task, task, "the solve of the session's views")

    async def _run(self, task: Callable, args: tuple, what: str) -> Any:
        """A task on the pool, its deadline and a dead worker answered as problems."""
        future = self._pool.schedule(task, args=args, timeout=self.timeout_s)
        try:
            return await asyncio.wrap_future(future)
        except TimeoutError as exc:
            raise SolveTimeout(f"{what} did not finish within {self.timeout_s:g} s") from exc
        except ProcessExpired as exc:
            raise ProblemError(
                503,
                "solver-crashed",
                "Solver crashed",
                f"the solver process stopped during {what} ({exc}); retry.",
                headers={"Retry-After": str(RETRY_AFTER_SECONDS)},
            ) from exc
