"""Cap request bodies while they stream: in size, so a chunked upload cannot bypass the limit,
and in time, so a client that sends half a body and stalls cannot hold its place for ever.

``Content-Length`` is checked first for a fast refusal, but never trusted: the bytes actually
received are counted, and the request fails with 413 the moment they pass the cap. The body
must arrive within ``body_timeout_s`` of the request's start, or it fails with 408. Once the
body is complete the deadline no longer applies: later ``receive`` calls only wait for the
client to disconnect.
"""

import time

import anyio
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.problems import ProblemError, problem_response


class UploadTooLarge(ProblemError):
    def __init__(self, limit: int) -> None:
        super().__init__(
            413, "upload-too-large", "Upload too large", f"the request body exceeds the cap of {limit} bytes"
        )


class BodyTimeout(ProblemError):
    def __init__(self, seconds: float, received: int) -> None:
        super().__init__(
            408,
            "body-timeout",
            "Request body too slow",
            f"the request body was not complete {seconds:g} s after its headers ({received} bytes received)",
            headers={"Connection": "close"},
        )


class UploadLimitMiddleware:
    """Pure ASGI middleware: wraps ``receive`` to count body bytes against the size cap and the
    deadline."""

    def __init__(self, app: ASGIApp, max_bytes: int, body_timeout_s: float) -> None:
        self.app = app
        self.max_bytes = max_bytes
        self.body_timeout_s = body_timeout_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > self.max_bytes):
            error = UploadTooLarge(self.max_bytes)
            await problem_response(413, error.slug, error.title, error.detail)(scope, receive, send)
            return
        deadline = time.monotonic() + self.body_timeout_s
        received = 0
        complete = False

        async def limited_receive() -> Message:
            nonlocal received, complete
            if complete:
                return await receive()
            with anyio.move_on_after(deadline - time.monotonic()) as waiting:
                message = await receive()
            if waiting.cancelled_caught:
                raise BodyTimeout(self.body_timeout_s, received)
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                complete = not message.get("more_body", False)
                if received > self.max_bytes:
                    raise UploadTooLarge(self.max_bytes)
            return message

        await self.app(scope, limited_receive, send)
