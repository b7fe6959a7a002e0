"""Warnings for unit slips: a shape, or a set of operands, whose size no human scan has.

A body in millimetres sent as metres is a valid surface, 1 386 866 m² large: its spectrum
(~1e-6 1/m²) was answered with a 200, and the union, localization and retrieval built on it
were meaningless. A spectrum is answered whatever the size (a statue is not a person), with a
warning that says what looks wrong and which unit would make it right; but a shape of a size no
body part has is not placed on the body (:func:`placeable_size`): placed anyway, it landed with
full confidence on a hand.
"""

import numpy as np

from app.core.errors import InputError
from app.geometry.io import UNIT_TO_METRES

PLAUSIBLE_AREA_M2 = (0.01, 10.0)  # a hand's palm to a whole body, with room either side
MAX_SIZE_RATIO = 10.0  # between the operands of one request, in implied length


def area_warnings(area_m2: float, scale_to_metres: float) -> list[str]:
    """A warning when the area is outside PLAUSIBLE_AREA_M2, naming a unit that would fit."""
    low, high = PLAUSIBLE_AREA_M2
    if low <= area_m2 <= high:
        return []
    in_file_units = area_m2 / scale_to_metres**2
    fitting = [(unit, in_file_units * factor**2) for unit, factor in UNIT_TO_METRES.items()]
    fitting = [(unit, area) for unit, area in fitting if low <= area <= high]
    hint = f"; read in {fitting[0][0]} it would be {fitting[0][1]:.3g} m² (units={fitting[0][0]})" if fitting else ""
    return [f"the shape's area is {area_m2:.3g} m², outside the {low:g}–{high:g} m² of a human scan{hint}"]


class ImplausibleSize(InputError):
    """A shape to be placed on the body whose size no body part has, in the units it was sent in."""

    slug = "implausible-size"
    title = "No body part is this size"


def placeable_size(area_m2: float, scale_to_metres: float) -> None:
    """ImplausibleSize (naming a unit that would fit) for an area outside PLAUSIBLE_AREA_M2."""
    for warning in area_warnings(area_m2, scale_to_metres):
        raise ImplausibleSize(f"{warning}: not placed on the body")


def size_warnings(spectra: list[np.ndarray], sources: list[str]) -> list[str]:
    """A warning when two operands differ in implied size (1/√mean λ) by more than MAX_SIZE_RATIO."""
    sized = [
        (1 / np.sqrt(np.mean(spectrum[spectrum > 0])), source)
        for spectrum, source in zip(spectra, sources, strict=True)
        if np.any(spectrum > 0)
    ]
    if len(sized) < 2:
        return []
    (large, large_source), (small, small_source) = max(sized), min(sized)
    ratio = large / small
    if ratio <= MAX_SIZE_RATIO:
        return []
    return [
        f"{large_source} is {ratio:.0f}× the size of {small_source}, judged by their eigenvalues: "
        "a unit slip? (10× is cm against mm, 100× m against cm, 1000× m against mm)"
    ]
