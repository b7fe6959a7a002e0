"""Prometheus metrics: requests and latencies per route, eigen-solve and inference times.

Requests are labelled by the name of the endpoint that handled them (``delete_shape``), never by
the raw path, and by their method only when it is one HTTP defines (else ``other``): uvicorn
accepts any method token, and 3 000 made-up methods had grown ``/metrics`` from 45 KB to 25 MB.
Every label takes a bounded set of values, so a client cannot blow up the number of series.
Served at ``/metrics``.
"""

import time

from fastapi import APIRouter, Response
from prometheus_client import CONTENT_TYPE_LATEST, Counter, Gauge, Histogram, generate_latest
from starlette.types import ASGIApp, Message, Receive, Scope, Send

REQUESTS = Counter("spectral_unions_requests_total", "HTTP requests answered.", ["handler", "method", "status"])
LATENCY = Histogram("spectral_unions_request_seconds", "Time to answer a request.", ["handler"])
UPLOADS_IN_FLIGHT = Gauge(
    "spectral_unions_upload_requests_in_flight", "Upload requests admitted and not yet answered (app.api.admission)."
)
UPLOAD_BYTES_IN_FLIGHT = Gauge(
    "spectral_unions_upload_bytes_in_flight",
    "Body bytes of the admitted upload requests, received so far or reserved (app.api.admission).",
)
UPLOADS_REFUSED = Counter(
    "spectral_unions_uploads_refused_total",
    "Upload requests refused 503 at admission, by what was full: requests or bytes.",
    ["full"],
)
SOLVES = Histogram(
    "spectral_unions_solve_seconds",
    "Laplacian assembly plus eigen-solve of one shape.",
    buckets=(0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1, 2.5, 5, 10, 30),
)
INFERENCE = Histogram(
    "spectral_unions_inference_seconds",
    "ONNX inference of one request.",
    ["model"],
    buckets=(0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25),
)

KNOWN_METHODS = frozenset({"GET", "HEAD", "POST", "PUT", "PATCH", "DELETE", "OPTIONS", "TRACE", "CONNECT"})

router = APIRouter(tags=["health"])


@router.get("/metrics", response_class=Response)
async def metrics() -> Response:
    """Prometheus text exposition."""
    return Response(generate_latest(), media_type=CONTENT_TYPE_LATEST)


class MetricsMiddleware:
    """Pure ASGI middleware: counts and times every HTTP request by endpoint and status."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        started = time.perf_counter()
        status = 500

        async def record_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
            await send(message)

        try:
            await self.app(scope, receive, record_status)
        finally:
            handler = getattr(scope.get("route"), "name", "unmatched")
            method = scope["method"] if scope["method"] in KNOWN_METHODS else "other"
            REQUESTS.labels(handler, method, str(status)).inc()
            LATENCY.labels(handler).observe(time.perf_counter() - started)
