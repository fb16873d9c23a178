"""The amplifier's real gain ratios (1 % and 5 % resistors, the multiplexer's leakage: [simulator].gain_errors)
measured on the white reference at every gain where it reads clean and above the noise, stored in the calibration
and used by auto-ranging instead of the nominal [detector].gains: the steps in a slice where the gain changes go.
Also the pure math of acquisition.calibration.measure_gain_factors and the DC amplifier's ladder."""

from __future__ import annotations

import json

import numpy as np
import pytest

from acquisition.calibration import Reading, measure_gain_factors
from acquisition.cli import main
from acquisition.devices.autorange import AutoRanger
from tests.test_acq_support import ground_truth, integration_times, make_raw, read, write_config

#: the real gains: 1 -> 0.96, 10 -> 1.03, 100 -> exact (the white reference is read there), 1000 -> 1.01
ERRORS = [-0.04, 0.03, 0.0, 0.01, 0.0]


def glossy_raw(gain_ratios: str) -> dict:
    """A glossy sample whose specular peak at theta_i = 30 is read at gains 100, 10 and 1, its flanks at 100."""
    raw = make_raw({"plan": {"theta_i_deg": [30.0], "theta_o_min_deg": 18.0, "theta_o_max_deg": 42.0,
                             "theta_o_step_deg": 1.0, "repeats": 8},
                    "calibration": {"gain_ratios": gain_ratios},
                    "simulator": {"gain_errors": ERRORS, "read_noise": 1.0}})  # gain 1 known to 0.1 %
    raw["material"] = {"name": "glossy", "lobes": [{"type": "lambert", "albedo": 0.5},
                                                   {"type": "ggx", "alpha": 0.02, "specular": 0.9, "f0": 0.04}]}
    return raw


def capture(tmp_path, gain_ratios: str):
    raw = glossy_raw(gain_ratios)
    out = tmp_path / gain_ratios
    assert main(["--config", str(write_config(tmp_path / f"{gain_ratios}.toml", raw)), "--out", str(out),
                 "--no-progress"]) == 0
    s = read(out / "slice.csv")
    gains = integration_times(out, s)[:, 1]
    rel = s.values[:, 0] / ground_truth(raw, s)[:, 0] - 1.0
    return s, gains, rel, out


def step(gains: np.ndarray, rel: np.ndarray, g: float) -> float:
    """The mean relative error of the points read at gain g minus that of the points at the reference's gain."""
    return float(np.mean(rel[gains == g]) - np.mean(rel[gains == 100.0]))


def test_measured_gain_ratios_remove_the_steps_at_range_changes(tmp_path):
    s_nom, g_nom, rel_nom, _ = capture(tmp_path, "nominal")
    s, g, rel, out = capture(tmp_path, "measured")
    assert {1.0, 10.0, 100.0} <= set(g) and set(g) == set(g_nom)  # the same slice, the same gains
    # nominal ratios: the points at gains 10 and 1 are off by their resistors' errors
    assert step(g_nom, rel_nom, 10.0) == pytest.approx(0.03, abs=0.006)  # a gain 3 % high reads 3 % high
    assert step(g_nom, rel_nom, 1.0) == pytest.approx(-0.04, abs=0.006)
    # measured ratios: no step
    assert abs(step(g, rel, 10.0)) < 0.006 and abs(step(g, rel, 1.0)) < 0.006
    cal = s.meta["calibration"]
    assert cal["gain_factors"]["10"] == pytest.approx(1.03, abs=0.003)
    assert cal["gain_factors"]["1"] == pytest.approx(0.96, abs=0.004)
    assert cal["gain_factors"]["100"] == 1.0 and cal["gain_factors"]["1000"] == 1.0  # not measurable: nominal
    assert sorted(cal["gain_factors_measured"]) == [1.0, 10.0]
    assert "gain_factors" not in s_nom.meta["calibration"]
    log = (out / "capture.log").read_text()
    assert "gain ratios measured on the white reference (real / nominal, relative to gain 100): 10: 1.03" in log
    assert json.loads((out / "capture.json").read_text())["runs"]


def reading(mean: float, std: float = 1.0, n: int = 32, sat: int = 0) -> Reading:
    return Reading(np.array([mean]), np.array([std]), n, sat)


def test_gain_factors_from_the_reference_at_every_gain():
    dark = reading(200.0, 2.0)
    at = {10000.0: (reading(65535.0, 0.0, sat=32), dark), 1000.0: (reading(60000.0, 50.0), dark),
          100.0: (reading(200.0 + 30000.0, 30.0), dark), 10.0: (reading(200.0 + 3090.0, 6.0), dark),
          1.0: (reading(200.0 + 288.0, 2.0), dark)}
    f, measured = measure_gain_factors(at, 100.0, 65535.0)
    assert measured == (10.0, 1.0)
    assert f[10.0] == pytest.approx(1.03) and f[1.0] == pytest.approx(0.96)
    assert f[100.0] == f[1000.0] == f[10000.0] == 1.0  # above the reference's gain: saturated, nominal
    noisy = {**at, 1.0: (reading(200.0 + 288.0, 60.0), dark)}  # 288 +- 11: not known to 0.2 %
    f, measured = measure_gain_factors(noisy, 100.0, 65535.0)
    assert measured == (10.0,) and f[1.0] == f[10.0]  # the nominal ratio to its measured neighbour
    wild = {**at, 10.0: (reading(200.0 + 6000.0, 6.0), dark)}  # twice the nominal: not a resistor's error
    assert measure_gain_factors(wild, 100.0, 65535.0)[1] == (1.0,)


class DC:
    """A detector board's driver as auto-ranging sees it: a DC amplifier (DETECTOR? amplifier=dc)."""

    integration_time_s = 0.01
    saturation = 81840.0
    dc_amplifier = True


def test_a_dc_amplifier_is_ranged_over_its_gains_only():
    gains = (1.0, 10.0, 100.0)
    r = AutoRanger(DC(), 0.01, 1e-5, read_dark=lambda: reading(0.0), gains=gains)
    assert r.ladder == [0.01, 0.01, 0.01] and [g for g, _ in r.settings] == [100.0, 10.0, 1.0]
    DC.dc_amplifier = False
    try:  # an integrating detector: the shorter times after the lowest gain
        r = AutoRanger(DC(), 0.01, 1e-5, read_dark=lambda: reading(0.0), gains=gains)
        assert len(r.ladder) > 3 and min(r.ladder) == 1e-5
    finally:
        DC.dc_amplifier = True
