"""What a placed part covers on the template, and the token a client keeps it by.

A cover is two things read from one placed density (:class:`app.inference.correspondence.
TemplateRegions`): the region (which template vertices the part lies on: what overlaps,
boundaries and IoU are measured on) and each vertex's covered share (how much of the template
around it the part's area fills: what per-body-part coverage sums, so that a ragged camera view
is not counted as the whole area between its strips).

A cover is kept as bytes (:func:`cover_bytes`): the region bit-packed, then the share in
sixteenths, two vertices a byte (~9 KB for the 12 167-vertex template). A stored session view
keeps its cover so (as text, :func:`cover_text`); a client gets it signed and bound to its
spectrum (:mod:`app.inference.region_tokens`), so that a session which sends spectra with their
tokens, instead of its scans again, reads the same coverage and cannot be told another.
"""

import base64
import binascii
from dataclasses import dataclass

import numpy as np

from app.core.errors import InputError

COVER_TEXT_PREFIX = "region2:"
SHARE_LEVELS = 15  # a share is sent as round(share · 15): 4 bits


@dataclass(frozen=True)
class Cover:
    """A template region (V,) bool and each template vertex's covered share (V,) in 0 … 1."""

    region: np.ndarray
    share: np.ndarray

    @classmethod
    def of_region(cls, region: np.ndarray) -> "Cover":
        """A region whose every vertex is fully covered (and nothing else)."""
        return cls(region, region.astype(np.float64))


def united(covers: list[Cover]) -> Cover:
    """The union's cover: the union of the regions, each vertex's largest share."""
    return Cover(np.logical_or.reduce([c.region for c in covers]), np.maximum.reduce([c.share for c in covers]))


class InvalidRegion(InputError):
    """A region token that is not one of this template's regions."""

    slug = "invalid-region"
    title = "Invalid region"


def cover_bytes(cover: Cover) -> bytes:
    """A cover as bytes: the region bit-packed, then the shares in sixteenths, two a byte."""
    levels = np.rint(np.clip(cover.share, 0.0, 1.0) * SHARE_LEVELS).astype(np.uint8)
    if len(levels) % 2:
        levels = np.append(levels, 0)
    nibbles = (levels[0::2] << 4) | levels[1::2]
    return np.packbits(cover.region).tobytes() + nibbles.astype(np.uint8).tobytes()


def cover_of_bytes(payload: bytes, vertices: int, name: str) -> Cover:
    """The cover of :func:`cover_bytes`; InvalidRegion naming ``name`` when it is not a cover of
    a template of this many vertices, or holds no vertex."""
    bits, shares = (vertices + 7) // 8, (vertices + 1) // 2
    if len(payload) != bits + shares:
        raise InvalidRegion(
            f"{name} holds {len(payload)} bytes, not the {bits + shares} of this template's {vertices} vertices"
        )
    region = np.unpackbits(np.frombuffer(payload[:bits], np.uint8), count=vertices).astype(bool)
    if not region.any():
        raise InvalidRegion(f"{name} is an empty region")
    nibbles = np.frombuffer(payload[bits:], np.uint8)
    levels = np.column_stack([nibbles >> 4, nibbles & 0x0F]).ravel()[:vertices]
    return Cover(region, levels / SHARE_LEVELS)


def cover_text(cover: Cover) -> str:
    """A cover as the text a stored view keeps it by (not for clients: unsigned)."""
    return COVER_TEXT_PREFIX + base64.b64encode(cover_bytes(cover)).decode("ascii")


def cover_of_text(text: str, vertices: int, name: str) -> Cover:
    """The cover of :func:`cover_text`'s text."""
    if not text.startswith(COVER_TEXT_PREFIX):
        raise InvalidRegion(f"{name} is not a stored cover")
    try:
        payload = base64.b64decode(text[len(COVER_TEXT_PREFIX) :], validate=True)
    except binascii.Error:
        raise InvalidRegion(f"{name} is not valid base64") from None
    return cover_of_bytes(payload, vertices, name)
