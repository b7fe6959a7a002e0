"""JSON in form fields (``spectra``, ``boundary``), read so that no text gets past a 422.

``json.loads`` raises ``RecursionError`` on 5 000 nested brackets and ``ValueError`` past
Python's int-digits limit; a 400-digit integer parses but overflows ``float()`` and int64;
``true`` and ``"1"`` are not numbers, although numpy turns them into 1.0. Each of these is the
client's error, raised as the caller's problem class with the field's name.
"""

import json

import numpy as np

from app.core.errors import InputError
from app.geometry.errors import InvalidGeometry

MAX_INDEX = 2**31 - 1  # past any vertex cap, and within every integer type the solvers use


def loads(text: str, name: str, error: type[InputError]) -> object:
    """The field's JSON value, or ``error`` saying why it is not JSON."""
    try:
        return json.loads(text)
    except RecursionError:
        raise error(f"{name} nests too deeply to be read") from None
    except ValueError as exc:  # JSONDecodeError, and the int-digits limit
        raise error(f"{name} is not valid JSON: {exc}") from None


def number_list(value: object, name: str, error: type[InputError]) -> np.ndarray:
    """A JSON list of numbers (not booleans, not strings) as float64, or ``error``."""
    if not isinstance(value, list) or not all(_is_number(v) for v in value):
        raise error(f"{name} must be a list of numbers")
    try:
        return np.array([float(v) for v in value], dtype=np.float64)
    except OverflowError:
        raise error(f"{name} holds an integer too large for a float") from None


def index_list(value: object, name: str, error: type[InputError]) -> list[int]:
    """A JSON list of integers in [0, MAX_INDEX], or ``error``."""
    if not isinstance(value, list) or not all(isinstance(v, int) and not isinstance(v, bool) for v in value):
        raise error(f"{name} must be a list of integers")
    if any(not 0 <= v <= MAX_INDEX for v in value):
        raise error(f"{name} must hold indices in [0, {MAX_INDEX}]")
    return value


def boundary_indices(text: str | None) -> list[int] | None:
    """The ``boundary`` field (a point cloud's boundary point indices), as the API and CLI take it."""
    if text is None:
        return None
    return index_list(loads(text, "boundary", InvalidGeometry), "boundary", InvalidGeometry)


def _is_number(value: object) -> bool:
    return isinstance(value, int | float) and not isinstance(value, bool)
