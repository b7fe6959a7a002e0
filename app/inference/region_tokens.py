"""Region tokens a client can keep and send back, but not forge, alter or reuse for another part.

A token is the template cover the service placed a part on (:func:`app.inference.cover.
cover_bytes`), bound to what it was issued with: the part's spectrum (as float32) and the models'
version, and signed with an HMAC-SHA256 key of the service's. Sent back beside a spectrum
(``regions`` with ``spectra``), it is read only if the signature holds under one of the keys the
service accepts, the models are the ones it was placed by, and the spectrum sent is the one it was
issued with (its first eigenvalues, within :data:`SPECTRUM_TOLERANCE`): otherwise the request is
refused (422 ``untrusted-region``) rather than answered from a region that belongs to another part.

Keys rotate without breaking tokens in flight: the first key signs, every key listed verifies, and
each token names the key it was signed with (the first bytes of the key's hash).
"""

import base64
import binascii
import hashlib
import hmac
import struct

import numpy as np

from app.core.errors import InputError
from app.inference.cover import Cover, InvalidRegion, cover_bytes, cover_of_bytes

PREFIX = "region3:"
EARLIER_PREFIXES = ("region1:", "region2:")  # unsigned formats, no longer read
TAG_BYTES = 16  # HMAC-SHA256 truncated: forging needs 2^128 tries
ID_BYTES = 4
HEADER = struct.Struct(f"<{ID_BYTES}s{ID_BYTES}sH")  # key id, models' version id, eigenvalue count
SPECTRUM_TOLERANCE = 1e-5  # relative: a spectrum sent back with six significant digits still matches


class UntrustedRegion(InputError):
    """A region token the service did not issue for this spectrum and these models."""

    slug = "untrusted-region"
    title = "Region token not trusted"


def _digest_id(data: bytes) -> bytes:
    return hashlib.sha256(data).digest()[:ID_BYTES]


class RegionTokens:
    """Issues and reads region tokens under ``keys`` (the first signs) for models of ``version``."""

    def __init__(self, keys: list[bytes], version: str) -> None:
        if not keys or any(len(key) < 16 for key in keys):
            raise ValueError("region tokens need at least one key of 16 bytes or more")
        self._keys = {_digest_id(key): key for key in keys}
        self._signing = _digest_id(keys[0])
        self._version = _digest_id(version.encode())

    def _tag(self, key: bytes, body: bytes) -> bytes:
        return hmac.new(key, PREFIX.encode() + body, hashlib.sha256).digest()[:TAG_BYTES]

    def issue(self, cover: Cover, eigenvalues: np.ndarray) -> str:
        """The token of ``cover``, placed for the part whose spectrum is ``eigenvalues``."""
        values = np.asarray(eigenvalues, dtype="<f4")
        body = HEADER.pack(self._signing, self._version, len(values)) + values.tobytes() + cover_bytes(cover)
        tag = self._tag(self._keys[self._signing], body)
        return PREFIX + base64.urlsafe_b64encode(body).decode() + "." + base64.urlsafe_b64encode(tag).decode()

    def read(self, token: object, eigenvalues: np.ndarray, vertices: int, name: str) -> Cover:
        """The cover ``token`` carries, sent with ``eigenvalues``; InvalidRegion when it is no
        token, UntrustedRegion when it is not one this service issued for that spectrum."""
        body, tag = self._parts(token, name)
        if len(body) < HEADER.size:
            raise InvalidRegion(f"{name} is too short to be a region token")
        key_id, version_id, count = HEADER.unpack_from(body)
        key = self._keys.get(key_id)
        if key is None:
            raise UntrustedRegion(f"{name} was signed with a key this service does not hold (rotated out, or forged)")
        if not hmac.compare_digest(tag, self._tag(key, body)):
            raise UntrustedRegion(f"{name} does not carry this service's signature: it was altered or forged")
        if version_id != self._version:
            raise UntrustedRegion(f"{name} was placed by other models than these: place the part again")
        issued = np.frombuffer(body, "<f4", count, HEADER.size).astype(np.float64)
        sent = np.asarray(eigenvalues, dtype=np.float64)
        shared = min(len(issued), len(sent))
        if not np.allclose(sent[:shared], issued[:shared], rtol=SPECTRUM_TOLERANCE, atol=0.0):
            raise UntrustedRegion(f"{name} was issued for another part's spectrum than the one sent with it")
        return cover_of_bytes(body[HEADER.size + 4 * count :], vertices, name)

    @staticmethod
    def _parts(token: object, name: str) -> tuple[bytes, bytes]:
        if isinstance(token, str) and token.startswith(EARLIER_PREFIXES):
            raise UntrustedRegion(f"{name} is an unsigned token of an earlier format: place the part again")
        if not isinstance(token, str) or not token.startswith(PREFIX):
            raise InvalidRegion(f"{name} is not a region token (they start with {PREFIX!r})")
        body, _, tag = token[len(PREFIX) :].partition(".")
        try:
            return tuple(base64.b64decode(text, altchars=b"-_", validate=True) for text in (body, tag))  # type: ignore[return-value]
        except (binascii.Error, ValueError):
            raise InvalidRegion(f"{name} is not valid base64") from None
