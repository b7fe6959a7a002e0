"""The build's named random streams: no two names draw the same numbers, but the documented overlaps."""

import numpy as np

from training.data.streams import CHUNKED, LATER, SERIAL, chunk_stream, serial_stream

CHUNKS = 64


def _first_draws(generator: np.random.Generator) -> tuple[float, ...]:
    return tuple(generator.random(4))


def _overlaps(seed: int) -> set[tuple[str, str]]:
    """Every pair of (name, chunk) streams, serial ones included, that draw the same numbers."""
    streams = {f"serial {name}": serial_stream(seed, name) for name in (*SERIAL, *LATER)}
    streams |= {f"{name} {chunk}": chunk_stream(seed, name, chunk) for name in CHUNKED for chunk in range(CHUNKS)}
    seen: dict[tuple[float, ...], str] = {}
    found = set()
    for label, generator in streams.items():
        key = _first_draws(generator)
        if key in seen:
            found.add((seen[key], label))
        seen[key] = label
    return found


def test_only_the_overlaps_streams_py_documents_exist():
    documented = {(f"candidate {chunk}", f"triple {chunk}") for chunk in range(CHUNKS)}
    documented |= {(f"serial {name}", f"pair {word}") for name, word in SERIAL.items()}
    for seed in (0, 1):
        assert _overlaps(seed) == documented


def test_another_build_seed_draws_other_numbers():
    for name in (*SERIAL, *LATER):
        assert _first_draws(serial_stream(0, name)) != _first_draws(serial_stream(1, name))
    for name in CHUNKED:
        assert _first_draws(chunk_stream(0, name, 3)) != _first_draws(chunk_stream(1, name, 3))
