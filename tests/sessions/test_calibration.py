"""σ of session unions solved on their views, and how unregistered sessions are read: the band a
session's view count falls in, and a calibration file that does not hold what it says refused."""

import json

import numpy as np
import pytest

from app.sessions.calibration import SessionCalibration


def calibration_file(tmp_path, fused, aligned) -> object:
    path = tmp_path / "sessions.json"
    path.write_text(json.dumps({"methods": {"fused": {"bands": fused}, "aligned": {"bands": aligned}}}))
    return path


FUSED = [{"views_up_to": 3, "relative_sigma": [0.1, 0.2]}, {"views_up_to": 8, "relative_sigma": [0.3, 0.4]}]
ALIGNED = [
    {"views_up_to": 3, "relative_sigma": [0.2, 0.2], "unregistered_by": "learned-chain"},
    {"views_up_to": 8, "relative_sigma": [0.5, 0.5], "unregistered_by": "aligned"},
]


def test_a_session_takes_its_band_s_relative_sigma_and_the_last_band_beyond(tmp_path):
    calibration = SessionCalibration.load(calibration_file(tmp_path, FUSED, ALIGNED), k=2)
    values = np.array([10.0, 20.0])
    np.testing.assert_allclose(calibration.fused.sigma(values, 2), [1.0, 4.0])
    np.testing.assert_allclose(calibration.fused.sigma(values, 3), [1.0, 4.0])
    np.testing.assert_allclose(calibration.fused.sigma(values, 4), [3.0, 8.0])
    np.testing.assert_allclose(calibration.fused.sigma(values, 40), [3.0, 8.0])
    np.testing.assert_allclose(calibration.aligned.sigma(values, 5), [5.0, 10.0])
    assert [calibration.unregistered_by(n) for n in (2, 3, 4, 40)] == ["learned-chain"] * 2 + ["aligned"] * 2


@pytest.mark.parametrize(
    "fused, aligned",
    [
        ([{"views_up_to": 3, "relative_sigma": [0.1]}], ALIGNED),  # not k values
        ([{"views_up_to": 3, "relative_sigma": [0.1, -0.2]}], ALIGNED),
        ([{"views_up_to": 3, "relative_sigma": [0.1, float("nan")]}], ALIGNED),
        (FUSED[::-1], ALIGNED),
        (FUSED, [{**band, "unregistered_by": "guess"} for band in ALIGNED]),
    ],
)
def test_a_calibration_that_is_not_one_is_refused(tmp_path, fused, aligned):
    with pytest.raises(ValueError):
        SessionCalibration.load(calibration_file(tmp_path, fused, aligned), k=2)
