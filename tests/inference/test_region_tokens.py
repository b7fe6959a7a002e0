"""Region tokens (:mod:`app.inference.region_tokens`): what a token carries comes back only to
the spectrum and models it was issued for, under a key the service holds.

The truths are the token's laws, hand-checked: a token read with the spectrum it was issued with
gives back its cover (the share to its sixteenths), also when the spectrum is sent rounded to six
significant digits or cut to its first eigenvalues; any other spectrum, another model version, a
changed byte, a key rotated out or an earlier unsigned format is refused, each saying why; a
token signed under the old key still reads while that key is listed after the new one.
"""

import base64

import numpy as np
import pytest
from pydantic import ValidationError

from app.core.config import Settings
from app.inference.cover import Cover, InvalidRegion, cover_text
from app.inference.region_tokens import RegionTokens, UntrustedRegion

KEY, NEW_KEY = b"k" * 32, b"n" * 32
SPECTRUM = np.array([2.5, 6.25, 9.125, 14.0625, 20.0])


@pytest.fixture()
def cover() -> Cover:
    region = np.array([True, False, True, True, False, False, True, True, True])
    return Cover(region, np.array([1.0, 0.2, 0.6, 0.0, 0.0, 0.0, 1 / 15, 1.0, 0.5]))


def test_a_token_read_with_its_own_spectrum_gives_back_its_cover(cover):
    tokens = RegionTokens([KEY], "v1")
    token = tokens.issue(cover, SPECTRUM)
    for sent in (SPECTRUM, np.array([float(f"{v:.6g}") for v in SPECTRUM]), SPECTRUM[:3]):
        back = tokens.read(token, sent, 9, "regions[0]")
        np.testing.assert_array_equal(back.region, cover.region)
        assert np.abs(back.share - cover.share).max() <= 0.5 / 15 + 1e-12


def test_a_token_sent_with_another_part_s_spectrum_is_refused(cover):
    tokens = RegionTokens([KEY], "v1")
    token = tokens.issue(cover, SPECTRUM)
    other = SPECTRUM.copy()
    other[4] *= 1.001
    with pytest.raises(UntrustedRegion, match="another part's spectrum"):
        tokens.read(token, other, 9, "regions[0]")


def test_a_token_of_other_models_is_refused(cover):
    token = RegionTokens([KEY], "v1").issue(cover, SPECTRUM)
    with pytest.raises(UntrustedRegion, match="other models"):
        RegionTokens([KEY], "v2").read(token, SPECTRUM, 9, "regions[0]")


def test_a_changed_byte_is_refused_as_forged(cover):
    tokens = RegionTokens([KEY], "v1")
    token = tokens.issue(cover, SPECTRUM)
    body, _, tag = token.removeprefix("region3:").partition(".")
    raw = bytearray(base64.urlsafe_b64decode(body))
    raw[-1] ^= 0x01  # one vertex's share changed
    forged = "region3:" + base64.urlsafe_b64encode(bytes(raw)).decode() + "." + tag
    with pytest.raises(UntrustedRegion, match="altered or forged"):
        tokens.read(forged, SPECTRUM, 9, "regions[0]")
    with pytest.raises(UntrustedRegion, match="does not hold"):  # signed by a key the service never had
        tokens.read(RegionTokens([b"x" * 32], "v1").issue(cover, SPECTRUM), SPECTRUM, 9, "regions[0]")


def test_keys_rotate_without_breaking_tokens_in_flight(cover):
    old = RegionTokens([KEY], "v1").issue(cover, SPECTRUM)
    rotated = RegionTokens([NEW_KEY, KEY], "v1")
    assert rotated.read(old, SPECTRUM, 9, "regions[0]").region.sum() == cover.region.sum()
    new = rotated.issue(cover, SPECTRUM)
    with pytest.raises(UntrustedRegion, match="does not hold"):  # the old key retired: its tokens no longer read
        RegionTokens([NEW_KEY], "v1").read(old, SPECTRUM, 9, "regions[0]")
    assert RegionTokens([NEW_KEY], "v1").read(new, SPECTRUM, 9, "regions[0]").region.sum() == cover.region.sum()


def test_earlier_formats_and_non_tokens_are_refused(cover):
    tokens = RegionTokens([KEY], "v1")
    with pytest.raises(UntrustedRegion, match="earlier format"):
        tokens.read(cover_text(cover), SPECTRUM, 9, "regions[0]")
    with pytest.raises(UntrustedRegion, match="earlier format"):
        tokens.read("region1:" + base64.b64encode(np.packbits(cover.region).tobytes()).decode(), SPECTRUM, 9, "r")
    for text in (None, 3, "region3:!!!.AA", "hello"):
        with pytest.raises(InvalidRegion):
            tokens.read(text, SPECTRUM, 9, "regions[0]")


def test_short_keys_are_refused():
    with pytest.raises(ValueError, match="16 bytes"):
        RegionTokens([b"short"], "v1")


def test_the_configured_keys_are_read_signing_one_first_and_short_ones_refused_at_start():
    settings = Settings(region_token_keys=" " + "n" * 20 + " ," + "k" * 16)
    assert settings.token_keys() == [b"n" * 20, b"k" * 16] and Settings().token_keys() is None
    with pytest.raises(ValidationError, match="16 characters"):
        Settings(region_token_keys="k" * 16 + ",short")
