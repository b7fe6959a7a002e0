"""Admission counts solves, not requests: a request takes a place for every file it solves, so
the uploads after a union of many files are refused at once instead of queueing behind it
(a union of 32 files held one place, and an upload behind it waited 12 s)."""

import asyncio

from starlette.types import Receive, Scope, Send

from app.api.admission import AdmissionMiddleware, take_solves


class _State:
    def __init__(self, scope: Scope) -> None:
        self.admission = scope["state"].get("admission")


def _scope() -> dict:
    headers = [(b"content-type", b"multipart/form-data; boundary=b"), (b"content-length", b"10")]
    return {"type": "http", "path": "/v1/union", "headers": headers, "method": "POST"}


async def _receive() -> dict:
    return {"type": "http.request", "body": b"0123456789", "more_body": False}


def _gate(capacity: int, solving: asyncio.Event, release: asyncio.Event, solves: dict[str, int]):
    async def app(scope: Scope, receive: Receive, send: Send) -> None:
        await receive()
        take_solves(_State(scope), solves[scope["path"]])
        solving.set()
        await release.wait()
        await send({"type": "http.response.start", "status": 200, "headers": []})
        await send({"type": "http.response.body", "body": b""})

    return AdmissionMiddleware(app, capacity=capacity, byte_budget=1 << 30, max_body_bytes=1 << 20)


async def _status(gate, scope: dict) -> int:
    sent = []

    async def send(message: dict) -> None:
        sent.append(message)

    await gate(scope, _receive, send)
    return next(m["status"] for m in sent if m["type"] == "http.response.start")


def _run(capacity: int, first_solves: int) -> tuple[int, int, int]:
    """A first request solving ``first_solves`` files, held while a one-file upload arrives:
    (the second's status, the places taken while both were in, the places left after)."""

    async def scenario():
        solving, release = asyncio.Event(), asyncio.Event()
        gate = _gate(capacity, solving, release, {"/v1/union": first_solves, "/v1/spectrum": 1})
        first = asyncio.create_task(_status(gate, _scope()))
        await solving.wait()
        taken = gate.places
        second_scope = _scope() | {"path": "/v1/spectrum"}
        second = asyncio.create_task(_status(gate, second_scope))
        await asyncio.sleep(0.01)
        release.set()
        statuses = await asyncio.gather(first, second)
        assert statuses[0] == 200  # an admitted request is never refused for its own size
        return statuses[1], taken, gate.places

    return asyncio.run(scenario())


def test_a_union_of_many_files_takes_a_place_for_each_and_the_next_upload_is_refused():
    status, taken, left = _run(capacity=4, first_solves=6)
    assert (status, taken, left) == (503, 4, 0)


def test_a_union_that_leaves_places_lets_the_next_upload_in():
    status, taken, left = _run(capacity=4, first_solves=2)
    assert (status, taken, left) == (200, 2, 0)


def test_a_one_file_request_takes_its_one_place():
    status, taken, left = _run(capacity=2, first_solves=1)
    assert (status, taken, left) == (200, 1, 0)
