"""Cap request bodies while they stream, so a chunked upload cannot bypass the limit.

``Content-Length`` is checked first for a fast refusal, but never trusted: the bytes actually
received are counted, and the request fails with 413 the moment they pass the cap.
"""

from starlette.types import ASGIApp, Message, Receive, Scope, Send

from app.api.problems import ProblemError, problem_response


class UploadTooLarge(ProblemError):
    def __init__(self, limit: int) -> None:
        super().__init__(
            413, "upload-too-large", "Upload too large", f"the request body exceeds the cap of {limit} bytes"
        )


class UploadLimitMiddleware:
    """Pure ASGI middleware: wraps ``receive`` to count body bytes."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        declared = dict(scope["headers"]).get(b"content-length")
        if declared is not None and (not declared.isdigit() or int(declared) > self.max_bytes):
            error = UploadTooLarge(self.max_bytes)
            await problem_response(413, error.slug, error.title, error.detail)(scope, receive, send)
            return
        received = 0

        async def limited_receive() -> Message:
            nonlocal received
            message = await receive()
            if message["type"] == "http.request":
                received += len(message.get("body", b""))
                if received > self.max_bytes:
                    raise UploadTooLarge(self.max_bytes)
            return message

        await self.app(scope, limited_receive, send)
