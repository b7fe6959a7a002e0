"""The ``Retry-After`` of an overloaded refusal: when the first request in flight is likely done,
from how long requests took lately (hand-checked medians)."""

import time

import pytest

from app.api.admission import AdmissionMiddleware, ServiceTimes, Ticket
from app.api.solver import RETRY_AFTER_SECONDS


def test_a_request_in_flight_is_expected_to_take_what_longer_ones_took_beyond_its_age():
    times = ServiceTimes()
    for seconds in (1, 2, 3, 10, 20):
        times.record(seconds)
    assert times.next_free([2.5]) == pytest.approx(7.5)  # median of 0.5, 7.5, 17.5
    assert times.next_free([0.5]) == pytest.approx(2.5)  # median of 0.5, 1.5, 2.5, 9.5, 19.5
    assert times.next_free([2.5, 0.5]) == pytest.approx(2.5)  # the first place to free
    assert times.next_free([30.0]) == pytest.approx(30.0)  # past every recent one: as long again
    assert times.next_free([]) == 0.0


def test_a_refusal_behind_a_heavy_upload_says_how_long_it_will_likely_hold():
    async def app(scope, receive, send):  # never called: only the estimate is read
        raise AssertionError

    gate = AdmissionMiddleware(app, capacity=1, byte_budget=1 << 20, max_body_bytes=1 << 20)
    assert gate.retry_after() == RETRY_AFTER_SECONDS  # nothing in flight
    for _ in range(10):
        gate.times.record(0.2)
    heavy = Ticket(gate)
    heavy.started = time.monotonic() - 40.0
    gate.tickets.add(heavy)
    assert 40 <= gate.retry_after() <= 42
    light = Ticket(gate)
    gate.tickets.add(light)
    assert gate.retry_after() == RETRY_AFTER_SECONDS  # a place frees within a second
