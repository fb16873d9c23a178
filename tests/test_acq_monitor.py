"""Ratio readings ([detector].monitor): the source monitor's rate during a reading over the white reference's
multiplies the net signal (acquisition/calibration.py), kept through pooling and a resumed capture's metadata;
without a monitor the calibration says why it cannot convert. The firmware's end of it (a drifting source divided
out of a whole capture): tests/test_firmware_faults.py,
test_ratio_readings_divide_a_drifting_source_out_of_a_capture."""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.calibration import Calibration, Reading, pool


def _cal(monitor: bool, ref_monitor: float | None = 2000.0) -> Calibration:
    dark = Reading(np.array([10.0]), np.array([1.0]), 8)
    ref = Reading(np.array([1010.0]), np.array([5.0]), 8, monitor=ref_monitor)
    return Calibration("relative", dark, ref, np.array([0.99]), 10.0, monitor=monitor)


def test_a_ratio_reading_divides_the_sources_power_out():
    plain, ratio = _cal(False), _cal(True)
    at_ref = Reading(np.array([510.0]), np.array([4.0]), 4, monitor=2000.0)  # the source as at the reference
    brighter = Reading(np.array([1010.0]), np.array([8.0]), 4, monitor=4000.0)  # twice the power: twice the net
    f0, s0 = plain.brdf(at_ref, 30.0)
    assert np.allclose(ratio.brdf(at_ref, 30.0), (f0, s0))
    f1, s1 = ratio.brdf(brighter, 30.0)
    assert np.allclose(f1, f0) and np.allclose(s1, s0)  # twice the std of the mean, times the factor 1/2
    assert np.allclose(plain.brdf(brighter, 30.0)[0], 2 * f0)  # without the ratio the drift stays in


@pytest.mark.parametrize("reading_monitor, ref_monitor, what", [
    (None, 2000.0, "the reading has no monitor= field"),
    (2000.0, None, "the white reference has no monitor= field"),
    (0.0, 2000.0, "no monitor photodiode on A1"),
])
def test_a_ratio_reading_without_the_monitor_says_why(reading_monitor, ref_monitor, what):
    rd = Reading(np.array([510.0]), np.array([4.0]), 4, monitor=reading_monitor)
    with pytest.raises(ValueError, match=what):
        _cal(True, ref_monitor).brdf(rd, 30.0)


def test_the_monitor_rate_is_pooled_by_repeats_and_kept_in_the_metadata():
    a = Reading(np.array([1.0]), np.array([0.1]), 3, monitor=100.0)
    b = Reading(np.array([1.0]), np.array([0.1]), 1, monitor=200.0)
    assert pool(a, b).monitor == pytest.approx(125.0)
    assert pool(a, Reading(np.array([1.0]), np.array([0.1]), 1)).monitor is None  # not half a ratio
    assert Reading.from_meta(a.to_meta()).monitor == 100.0
    assert "monitor_per_s" not in Reading(np.ones(1), np.zeros(1), 1).to_meta()
    meta = _cal(True).to_meta()
    assert meta["monitor_ratio"] is True and meta["reference_reading"]["monitor_per_s"] == 2000.0
    assert "monitor_ratio" not in _cal(False).to_meta()
