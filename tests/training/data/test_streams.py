"""The build's named random streams: no two names draw the same numbers, but the one documented pair."""

import numpy as np

from training.data.streams import CHUNKED, SERIAL, chunk_stream, serial_stream

SHARED = {"candidate", "triple"}  # one word, kept until the next full rebuild (streams.py says why)


def _first_draws(generator: np.random.Generator) -> tuple[float, ...]:
    return tuple(generator.random(4))


def test_serial_streams_are_distinct_from_each_other_and_from_every_chunk_stream():
    draws = {name: _first_draws(serial_stream(0, name)) for name in SERIAL}
    assert len(set(draws.values())) == len(SERIAL)
    chunked = {_first_draws(chunk_stream(0, name, chunk)) for name in CHUNKED for chunk in range(64)}
    assert not chunked & set(draws.values())


def test_chunk_streams_are_distinct_per_kind_and_chunk_except_the_documented_pair():
    seen: dict[tuple[float, ...], str] = {}
    for name in CHUNKED:
        for chunk in range(64):
            key = _first_draws(chunk_stream(0, name, chunk))
            if key in seen:
                assert {seen[key], name} == SHARED, (seen[key], name, chunk)
            seen[key] = name
    assert len({CHUNKED[name] for name in SHARED}) == 1


def test_another_build_seed_draws_other_numbers():
    for name in SERIAL:
        assert _first_draws(serial_stream(0, name)) != _first_draws(serial_stream(1, name))
