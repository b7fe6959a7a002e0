"""What a placed part covers on the template, and the token a client keeps it by.

A cover is two things read from one placed density (:class:`app.inference.correspondence.
TemplateRegions`): the region (which template vertices the part lies on: what overlaps,
boundaries and IoU are measured on) and each vertex's covered share (how much of the template
around it the part's area fills: what per-body-part coverage sums, so that a ragged camera view
is not counted as the whole area between its strips).

A token carries both, so that a session which sends spectra with their tokens, instead of its
scans again, reads the same coverage: the region bit-packed, then the share in sixteenths, two
vertices a byte (~10 KB of text for the 12 167-vertex template). Tokens of the earlier format
(``region1:``, the region alone) are still read, their share being the region itself.
"""

import base64
import binascii
from dataclasses import dataclass

import numpy as np

from app.core.errors import InputError

REGION_TOKEN_PREFIX = "region2:"
REGION_ONLY_PREFIX = "region1:"
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


def region_token(cover: Cover) -> str:
    """A cover as text a client keeps and sends back (``regions``)."""
    levels = np.rint(np.clip(cover.share, 0.0, 1.0) * SHARE_LEVELS).astype(np.uint8)
    if len(levels) % 2:
        levels = np.append(levels, 0)
    nibbles = (levels[0::2] << 4) | levels[1::2]
    payload = np.packbits(cover.region).tobytes() + nibbles.astype(np.uint8).tobytes()
    return REGION_TOKEN_PREFIX + base64.b64encode(payload).decode("ascii")


def region_from_token(token: object, vertices: int, name: str) -> Cover:
    """The cover of :func:`region_token`'s text (or of an earlier region-only token);
    InvalidRegion naming ``name`` when it is not a token of a template of this many vertices, or
    holds no vertex."""
    prefix = next(
        (p for p in (REGION_TOKEN_PREFIX, REGION_ONLY_PREFIX) if isinstance(token, str) and token.startswith(p)), None
    )
    if prefix is None:
        raise InvalidRegion(f"{name} is not a region token (they start with {REGION_TOKEN_PREFIX!r})")
    try:
        payload = base64.b64decode(token[len(prefix) :], validate=True)
    except binascii.Error:
        raise InvalidRegion(f"{name} is not valid base64") from None
    bits = (vertices + 7) // 8
    shares = (vertices + 1) // 2 if prefix == REGION_TOKEN_PREFIX else 0
    if len(payload) != bits + shares:
        raise InvalidRegion(
            f"{name} holds {len(payload)} bytes, not the {bits + shares} of this template's {vertices} vertices"
        )
    region = np.unpackbits(np.frombuffer(payload[:bits], np.uint8), count=vertices).astype(bool)
    if not region.any():
        raise InvalidRegion(f"{name} is an empty region")
    if not shares:
        return Cover.of_region(region)
    nibbles = np.frombuffer(payload[bits:], np.uint8)
    levels = np.column_stack([nibbles >> 4, nibbles & 0x0F]).ravel()[:vertices]
    return Cover(region, levels / SHARE_LEVELS)
