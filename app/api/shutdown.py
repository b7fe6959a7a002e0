"""Readiness flips the moment SIGTERM (or SIGINT) arrives, before the server starts draining.

uvicorn owns the signal handlers while it serves: on SIGTERM it stops accepting connections,
lets in-flight requests finish within ``timeout_graceful_shutdown`` and then runs the
lifespan's shutdown. Chaining onto its handler marks the app not ready first, so a probe that
reaches a draining replica (on a kept-alive connection, or just before the listener closes)
is told 503 rather than "ready".
"""

import signal
import threading
from types import FrameType

from fastapi import FastAPI

EXIT_SIGNALS = (signal.SIGTERM, signal.SIGINT)


def flip_readiness_on_exit_signals(app: FastAPI) -> None:
    """Wrap the current exit-signal handlers; only the main thread can, so in-process test
    clients (which run the lifespan in a worker thread) keep the handlers they have."""
    if threading.current_thread() is not threading.main_thread():
        return
    for number in EXIT_SIGNALS:
        previous = signal.getsignal(number)

        def handler(signum: int, frame: FrameType | None, previous=previous) -> None:
            app.state.ready = False
            if callable(previous):
                previous(signum, frame)

        signal.signal(number, handler)
