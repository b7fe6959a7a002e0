"""Admit or refuse an upload request when its headers arrive, before its body is read.

Counting uploads once they were parsed meant an overloaded server first received every body
before refusing it, and a two-file union could have its first file solved and its second
refused. Here a request that
carries a multipart body (every route that solves an upload takes one; a spectra-only form
is one too and passes in milliseconds) is counted in on its headers, whole: at most
``capacity`` such requests are in flight (solving or waiting for a solver), and their bodies
together stay under ``byte_budget``. A body is charged as its bytes arrive, after a reservation
of at most :data:`RESERVATION_BYTES` on admission: charged its declared length (or the upload cap
when chunked) up front, a few connections sending a byte now and then held the whole budget
and every other upload was refused. The rest get 503 ``overloaded`` at once, their
bodies unread, with a ``Retry-After`` of when the first request in flight is likely done
(:class:`ServiceTimes`), and ``/metrics`` counts them by what was full.

A place is one solve. A request is admitted on one place and takes one more for each further
file it solves, once its form is read and before any solve starts (:func:`take_solves`), as far
as places remain: a union of many files that held one place queued all its solves, and an
upload behind it waited for them; now it holds every place it can, and the uploads after it are
refused at once.
An admitted request is never refused for its own size.
A route that solves a shape of its own whatever its body holds (``/v1/reconstruct`` checks the
body it rebuilt; a session's ``/body`` and ``/identity`` fit a body) is counted in the same way
on any body, URL-encoded spectra included, so that no request reaches the solvers' queue
uncounted.
"""

import math
import time
from collections import deque

import numpy as np
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.metrics import UPLOAD_BYTES_IN_FLIGHT, UPLOADS_IN_FLIGHT, UPLOADS_REFUSED
from app.api.problems import problem_response
from app.api.solver import RETRY_AFTER_SECONDS

RESERVATION_BYTES = 1024 * 1024  # charged on admission; the body's bytes past it as they arrive
RECENT_REQUESTS = 64  # how many finished requests' durations say how long the ones in flight will take


class ServiceTimes:
    """How long admitted requests took lately, and so when a place is likely to free: what a
    refusal's ``Retry-After`` says. A fixed second said nothing true behind a heavy upload that
    held every place for a minute."""

    def __init__(self, size: int = RECENT_REQUESTS) -> None:
        self.recent: deque[float] = deque(maxlen=size)

    def record(self, seconds: float) -> None:
        self.recent.append(seconds)

    def next_free(self, elapsed: list[float]) -> float:
        """Seconds until the first of the requests in flight (each ``elapsed`` seconds in) is
        likely done: for each, the median of how much longer the recent requests that ran longer
        than it has took; a request that has run longer than every recent one is a heavy one,
        taken to need as long again (a fixed guess would be wrong for a short one or a long one)."""
        durations = np.asarray(self.recent, dtype=float)
        remaining = [float(np.median(durations[durations > e] - e)) if (durations > e).any() else e for e in elapsed]
        return min(remaining, default=0.0)


class Ticket:
    """An admitted request's places in :class:`AdmissionMiddleware` (``request.state.admission``)."""

    def __init__(self, gate: "AdmissionMiddleware") -> None:
        self.gate = gate
        self.places = 1
        self.started = time.monotonic()

    def take(self, solves: int) -> None:
        """Hold a place for each of ``solves``, beyond those held, as far as places remain."""
        extra = max(0, min(solves - self.places, self.gate.capacity - self.gate.places))
        self.gate.places += extra
        self.places += extra


def take_solves(state: object, solves: int) -> None:
    """Charge a request's admission ticket (its ``request.state``) for ``solves`` solves; a
    request the middleware did not count (no multipart body) has none and pays nothing."""
    ticket = getattr(state, "admission", None)
    if ticket is not None:
        ticket.take(solves)


class AdmissionMiddleware:
    """Pure ASGI middleware around the app; see the module docstring."""

    def __init__(
        self,
        app: ASGIApp,
        capacity: int,
        byte_budget: int,
        max_body_bytes: int,
        solving_paths: frozenset[str] = frozenset(),
        solving_suffixes: tuple[str, ...] = (),
    ) -> None:
        self.app = app
        self.solving_paths = solving_paths
        self.solving_suffixes = solving_suffixes  # paths with an id in them: a session's fitted body
        self.capacity = capacity
        self.byte_budget = byte_budget
        self.max_body_bytes = max_body_bytes
        self.places = 0
        self.bytes = 0
        self.tickets: set[Ticket] = set()
        self.times = ServiceTimes()

    def _solves(self, path: str) -> bool:
        """Whether a request without an upload still solves (a decoded or fitted body)."""
        return path in self.solving_paths or (bool(self.solving_suffixes) and path.endswith(self.solving_suffixes))

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = dict(scope["headers"]) if scope["type"] == "http" else {}
        multipart = headers.get(b"content-type", b"").lower().startswith(b"multipart/form-data")
        if not (multipart or (scope["type"] == "http" and self._solves(scope["path"]))):
            await self.app(scope, receive, send)
            return
        charge = min(_declared_length(headers, self.max_body_bytes), RESERVATION_BYTES)
        # No await between the check and the count: concurrent requests cannot all slip past.
        if self.places >= self.capacity or self.bytes + charge > self.byte_budget:
            UPLOADS_REFUSED.labels("requests" if self.places >= self.capacity else "bytes").inc()
            await self._refuse(scope, receive, send)
            return
        ticket = Ticket(self)
        self.tickets.add(ticket)
        self.places += 1
        scope.setdefault("state", {})["admission"] = ticket
        UPLOADS_IN_FLIGHT.inc()
        self._charge(charge)
        received = 0

        async def counted_receive() -> Message:
            nonlocal received, charge
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > charge:
                    self._charge(received - charge)
                    charge = received
            return message

        try:
            await self.app(scope, counted_receive, send)
        finally:
            self.places -= ticket.places
            self.tickets.discard(ticket)
            self.times.record(time.monotonic() - ticket.started)
            self._charge(-charge)
            UPLOADS_IN_FLIGHT.dec()

    def _charge(self, count: int) -> None:
        self.bytes += count
        UPLOAD_BYTES_IN_FLIGHT.set(self.bytes)

    def retry_after(self) -> int:
        """Whole seconds until a place is likely free (:class:`ServiceTimes`), at least
        RETRY_AFTER_SECONDS."""
        now = time.monotonic()
        wait = self.times.next_free([now - ticket.started for ticket in self.tickets])
        return max(RETRY_AFTER_SECONDS, math.ceil(wait))

    async def _refuse(self, scope: Scope, receive: Receive, send: Send) -> None:
        retry = self.retry_after()
        detail = (
            f"{self.places} solves ({self.bytes} bytes of their uploads) are already being received or run; "
            f"retry after {retry} s (when the first of them is likely done, from how long requests took lately)."
        )
        response = problem_response(503, "overloaded", "Overloaded", detail)
        response.headers["Retry-After"] = str(retry)
        # The body is never asked for: a client that sent ``Expect: 100-continue`` (curl does,
        # for large bodies) gets no 100 and never sends it; one that sends it anyway has it
        # discarded by uvicorn, and its connection stays usable (closing it on unread bytes
        # would reset it, and the client would see no 503 at all).
        await response(scope, receive, send)


def _declared_length(headers: dict[bytes, bytes], max_body_bytes: int) -> int:
    """The body length the headers declare; the cap when they declare none (chunked) or garbage
    (the upload limit refuses those with 413 before any byte is read)."""
    declared = headers.get(b"content-length", b"")
    return min(int(declared), max_body_bytes) if declared.isdigit() else max_body_bytes
