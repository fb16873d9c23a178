"""Detector auto-ranging: the ranging rules on a scripted detector, then hardware in the loop on the simulator
with a sharp specular lobe (GGX alpha 0.02) whose peak saturates the detector at the configured integration time:
complete captures that agree with the ground truth, the stop without auto-ranging, and a resume after a kill in
the middle of the auto-ranged region."""

from __future__ import annotations

import json
import os
import signal
import time

import numpy as np
import pytest

from acquisition.calibration import Reading
from acquisition.cli import main
from acquisition.devices.autorange import AutoRanger, ladder
from acquisition.errors import DeviceError
from tests.test_acq_support import (
    integration_times,
    keys,
    make_raw,
    popen_capture,
    read,
    run_capture,
    write_config,
    zscores,
)

T_REF = 0.01
WL = [float(w) for w in np.arange(400.0, 701.0, 20.0)]


# --- the ranging rules on a scripted detector ----------------------------------------------------------------


class FakeDetector:
    """Noise-free detector: reading = offset + dark_current * t + signal * t / T_REF per channel, clipped;
    ``forced`` = saturated-repeat counts to report on the next readings (transients)."""

    def __init__(self, offset: float = 200.0, dark_current: float = 3000.0, saturation: float = 65535.0) -> None:
        self.integration_time_s = T_REF
        self.saturation = saturation
        self.offset = offset
        self.dark_current = dark_current  # counts per second: the dark level grows with t
        self.signal = np.array([0.0])
        self.std = 0.0
        self.forced: list[int] = []
        self.reads: list[float] = []
        self.sizes: list[int] = []  # the repeats of each reading
        self.darks: list[float] = []
        self.int_commands = 0

    def set_integration_time(self, seconds: float) -> float:
        self.int_commands += 1
        self.integration_time_s = seconds
        return seconds

    def _dark_level(self) -> float:
        return self.offset + self.dark_current * self.integration_time_s

    def read(self, n: int) -> Reading:
        self.reads.append(self.integration_time_s)
        self.sizes.append(n)
        x = self._dark_level() + self.signal * self.integration_time_s / T_REF
        sat = n if np.any(x >= self.saturation) else 0
        if self.forced:
            sat = self.forced.pop(0)
        return Reading(np.minimum(x, self.saturation), np.full_like(x, self.std), n, sat)

    def dark(self, n: int) -> Reading:
        self.darks.append(self.integration_time_s)
        return Reading(np.full_like(self.signal, self._dark_level()), np.zeros_like(self.signal), n, 0)


def ranger_for(det: FakeDetector, t_min: float = 1e-5) -> AutoRanger:
    r = AutoRanger(det, T_REF, t_min, read_dark=lambda: det.dark(32))
    r.ref_dark = det.dark(32)
    det.darks.clear()
    return r


def test_ladder():
    assert ladder(0.01, 1e-5) == [0.01, 0.00316228, 0.001, 0.000316228, 0.0001, 3.16228e-05, 1e-05]
    assert ladder(0.05, 1e-3) == [0.05, 0.0158114, 0.005, 0.00158114, 0.001]
    assert ladder(0.01, 0.01) == [0.01]


def test_ranging_down_converts_exactly_and_caches_darks():
    det = FakeDetector()
    r = ranger_for(det)
    ref_dark = float(r.ref_dark.mean[0])
    det.signal = np.array([5.0e5])  # 7.6 x the saturation at T_REF
    g = r.read(4, "peak")
    # fully clipped at 0.01 s: two rungs down (0.001 s) reads 50,203 counts; 0.00316 s would not fit
    assert det.reads == [0.01, 0.001] and g.ranged and g.integration_time_s == 0.001 and g.readings == 2
    assert g.reading.mean[0] == pytest.approx(ref_dark + 5.0e5, rel=1e-12)  # the dark current is not assumed
    assert det.darks == [0.001] and g.overhead_s == pytest.approx(4 * 0.01 + 32 * 0.001)
    det.signal = np.array([3.0e5])  # the neighbour starts on the same rung: one reading, the cached dark
    g = r.read(4, "next")
    assert det.reads[2:] == [0.001] and g.readings == 1 and det.darks == [0.001]
    assert g.reading.mean[0] == pytest.approx(ref_dark + 3.0e5, rel=1e-12)
    det.signal = np.array([1000.0])  # a dim point: one short reading, then back to the reference
    g = r.read(4, "dim")
    assert det.reads[3:] == [0.001, 0.01] and not g.ranged and g.reading.mean[0] == ref_dark + 1000.0
    det.signal = np.array([1.0e12])
    with pytest.raises(DeviceError, match=r"bright: the detector saturates \(65535 counts\) even at the shortest "
                                          r"integration time, \[detector\].min_integration_time_s = 1e-05 s"):
        r.read(4, "bright")
    r.restore()
    assert det.integration_time_s == T_REF


def test_partial_saturation_is_read_again_and_near_saturation_ranges():
    det = FakeDetector(dark_current=0.0)
    r = ranger_for(det)
    det.signal = np.array([30000.0])
    det.forced = [1]  # a transient: one clipped repeat, gone on the second reading
    g = r.read(4, "transient")
    assert det.reads == [0.01, 0.01] and not g.ranged
    det.reads.clear()
    det.signal, det.std = np.array([52000.0]), 300.0  # not clipped, but above 80 % of the clip: one rung down
    g = r.read(4, "near")
    assert det.reads == [0.01, 0.00316228] and g.integration_time_s == 0.00316228
    assert g.reading.mean[0] == pytest.approx(200.0 + 52000.0)
    assert g.reading.std[0] == pytest.approx(300.0 * 0.01 / 0.00316228)


def test_spectrometer_ranges_on_the_brightest_pixel():
    det = FakeDetector()
    r = ranger_for(det)
    det.signal = np.array([1.0e3, 2.0e4, 2.0e5])  # only the last pixel saturates
    g = r.read(4, "spectrum")
    assert g.integration_time_s == 0.001
    np.testing.assert_allclose(g.reading.mean, r.ref_dark.mean + det.signal, rtol=1e-12)


def test_a_longer_setting_that_saturates_keeps_the_clean_shorter_reading():
    det = FakeDetector(dark_current=0.0)
    r = ranger_for(det)
    det.signal = np.array([1.0e5])
    det.forced = [4, 0, 2]  # 0.01 s clipped; 0.001 s clean (predicts 0.00316 s fits); 0.00316 s clips after all
    g = r.read(4, "p")
    assert det.reads == [0.01, 0.001, 0.00316228] and g.integration_time_s == 0.001 and g.readings == 3


def peak(to: np.ndarray | float) -> np.ndarray:
    """A specular peak at theta_o = 30 deg, 40 x the saturation at T_REF, over a floor of 1 % of it."""
    return np.atleast_1d(650.0 + 2.6e6 * np.exp(-0.5 * ((np.asarray(to, dtype=float) - 30.0) / 2.0) ** 2))


def sweep(r: AutoRanger, det: FakeDetector, tos, with_points: bool) -> list[int]:
    """Read theta_o = ``tos`` at theta_i = 30 in that order (``with_points``: each read as its point); the
    readings taken per point. Every reading is converted exactly, however it was ranged."""
    counts = []
    for to in tos:
        det.signal = peak(to)
        g = r.read(4, f"({to:g})", point=(30.0, float(to)) if with_points else None)
        assert g.reading.mean[0] == pytest.approx(float(r.ref_dark.mean[0]) + float(det.signal[0]), rel=1e-9)
        counts.append(g.readings)
    return counts


def test_the_first_reading_of_a_point_starts_on_the_setting_its_neighbours_predict():
    """Across a peak 1 deg at a time, the setting the last point needed (before) costs a reading wherever the
    signal crosses into another setting's range, up the slope and down; predicted from the neighbours' signal
    (their trend on one side) the first reading is on the right setting almost everywhere. A midpoint between two
    points read (adaptive refinement) starts on what they predict: one reading."""
    tos = np.arange(10.0, 51.0, 1.0)
    det = FakeDetector()
    sticky = sweep(ranger_for(det), det, tos, with_points=False)
    det = FakeDetector()
    r = ranger_for(det)
    predicted = sweep(r, det, tos, with_points=True)
    assert sum(sticky) - len(tos) >= 6  # the ladder walked at every crossing
    assert sum(predicted) - len(tos) <= 2, (predicted, sticky)
    assert r.predict((30.0, 29.5)) == r.predict((30.0, 30.0)) and r.predict((99.0, 30.0)) is None
    det.reads.clear()
    det.signal = peak(30.5)
    g = r.read(4, "midpoint", point=(30.0, 30.5))
    assert g.readings == 1 and len(det.reads) == 1


def test_a_guessed_setting_is_probed_with_a_few_repeats_and_the_rest_pooled():
    """The white reference (32 repeats, no neighbour to predict it) saturates at the reference setting: the
    search reads 4 repeats per setting, then the other 28 at the setting found, pooled with its probe; only the
    clipped probe was extra integration."""
    from acquisition.devices.autorange import PROBE_REPEATS

    det = FakeDetector(dark_current=0.0)
    r = ranger_for(det)
    det.signal, det.std = np.array([5.0e5]), 10.0
    g = r.read(32, "white reference", start=0)
    assert PROBE_REPEATS == 4 and det.sizes == [4, 4, 28] and det.reads == [0.01, 0.001, 0.001]
    assert g.reading.n == 32 and g.integration_time_s == 0.001 and g.readings == 2
    assert g.reading.mean[0] == pytest.approx(200.0 + 5.0e5)
    assert g.overhead_s == pytest.approx(4 * 0.01 + 32 * 0.001)  # the clipped probe and the new dark
    det.reads.clear(), det.sizes.clear()
    g = r.read(4, "a point", point=(30.0, 30.0))  # no more repeats than a probe: one reading as before
    assert det.sizes == [4] and g.readings == 1


# --- hardware in the loop ----------------------------------------------------------------------------------------


def sharp_raw(detector: str = "photodiode", motion: str = "dynamixel", over: dict | None = None) -> dict:
    """A glossy sample (Lambert 0.1 + GGX alpha 0.02) whose specular peak at theta_i = 30 is ~13 times the
    saturation at the configured integration time; outgoing angles 1 deg apart around the peak."""
    specular: object = 0.9
    extra: dict = {}
    if detector == "spectrometer":  # a spectral lobe: the long wavelengths saturate first
        specular = {"wavelengths_nm": WL, "values": [float(v) for v in np.linspace(0.3, 0.9, len(WL))]}
        extra = {"simulator": {"spectrometer": {"wl_min_nm": 400.0, "wl_max_nm": 700.0, "wl_step_nm": 20.0}}}
    raw = make_raw({"bench": {"motion": motion}, "detector": {"type": detector},
                    "plan": {"theta_o_min_deg": 22.0, "theta_o_max_deg": 38.0, "theta_o_step_deg": 1.0},
                    "simulator": {"source_power": 1.0e8}}, extra, over or {})
    del raw["detector"]["gains"]  # auto-ranging over integration time alone (gains: tests/test_acq_gains.py)
    raw["material"] = {"name": "sharp-ggx", "lobes": [
        {"type": "lambert", "albedo": 0.1}, {"type": "ggx", "alpha": 0.02, "specular": specular, "f0": 0.04}]}
    return raw


@pytest.mark.parametrize("detector, motion", [("photodiode", "dynamixel"), ("spectrometer", "serial")])
def test_sharp_peak_is_auto_ranged_and_matches_ground_truth(tmp_path, capsys, detector, motion):
    raw = sharp_raw(detector, motion)
    cfg = write_config(tmp_path / "sharp.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    assert "  auto-ranged " in capsys.readouterr().err
    s = read(out / "slice.csv")
    assert len(s) == 17 and s.values.shape[1] == (1 if detector == "photodiode" else len(WL))
    assert s.meta["detector"]["auto_range"] is True and s.meta["detector"]["integration_time_s"] == T_REF
    t = integration_times(out, s)
    peak = int(np.argmin(np.abs(s.theta_o_deg - 30.0)))
    assert t[peak] <= 0.001 and len(set(t[t < T_REF])) >= 2  # several settings around the peak
    assert np.all(t[np.abs(s.theta_o_deg - 30.0) >= 5.0] == T_REF)  # the flanks at the reference time
    z, rel = zscores(raw, s, t)
    assert np.all(np.abs(z) < 5.0), np.abs(z).max(axis=1)
    assert 0.3 < float(np.mean(z ** 2)) < 2.5
    near = np.abs(s.theta_o_deg - 30.0) <= 3.0
    assert np.all(np.abs(rel[near]) < 0.02), rel[near]
    sc = json.loads((out / "capture.json").read_text())
    ar = sc["auto_range"]
    assert ar["ranged_points"] == int(np.sum(t < T_REF)) == sum(ar["settings"].values())
    assert set(ar["darks"]) == set(ar["settings"]) and ar["overhead_s"] > 0
    assert sc["runs"][-1]["auto_range"]["readings_discarded"] > 0
    log = (out / "capture.log").read_text()
    assert "point (30, 30): auto-ranged to t_int = " in log and f"auto-ranging: {ar['ranged_points']} point(s)" in log


def test_without_auto_range_the_peak_stops_the_capture(tmp_path, capsys):
    cfg = write_config(tmp_path / "off.toml", sharp_raw(over={"detector": {"auto_range": False}}))
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "the detector saturates (65535 counts); reduce [detector].integration_time_s or the gain, or set " \
           "[detector].auto_range = true" in err and "--resume" in err
    assert "auto_range" not in json.loads((out / "capture.json").read_text())


def ranged_count(out) -> int:
    try:
        return int(json.loads((out / "capture.json").read_text()).get("auto_range", {}).get("ranged_points", 0))
    except (FileNotFoundError, json.JSONDecodeError):
        return 0


@pytest.mark.slow
def test_resume_after_kill_in_the_auto_ranged_region(tmp_path):
    """SIGKILL once two points of the peak were auto-ranged, resume: the samples equal an uninterrupted run's
    (none lost, none twice, the same settings), the darks per setting come from the run record."""
    slow = sharp_raw(over={"simulator": {"time_scale": 4.0}})
    cfg = write_config(tmp_path / "slow.toml", slow)
    out = tmp_path / "out"
    p = popen_capture("--config", str(cfg), "--out", str(out), "--no-progress")
    t_end = time.monotonic() + 30.0
    while ranged_count(out) < 2:
        assert p.poll() is None, p.communicate()
        assert time.monotonic() < t_end, "no auto-ranged point"
        time.sleep(0.005)
    os.kill(p.pid, signal.SIGKILL)
    p.communicate(timeout=30)
    before = read(out / "slice.csv")
    sc = json.loads((out / "capture.json").read_text())
    assert sc["status"] == "running" and 2 <= len(before) < 17 and sc["auto_range"]["darks"]
    fast = sharp_raw()
    cfg_fast = write_config(tmp_path / "fast.toml", fast)
    r = run_capture("--config", str(cfg_fast), "--out", str(out), "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    log = (out / "capture.log").read_text()
    assert "auto-ranging: reusing the dark level at" in log
    s = read(out / "slice.csv")  # the reader rejects duplicates
    ref = tmp_path / "uninterrupted"
    r2 = run_capture("--config", str(cfg_fast), "--out", str(ref), "--no-progress")
    assert r2.returncode == 0, r2.stderr
    s_ref = read(ref / "slice.csv")
    assert sorted(keys(s)) == sorted(keys(s_ref)) and len(s) == 17
    assert set(keys(before)) <= set(keys(s))
    for k in keys(before):  # samples taken before the kill are kept as they were
        i, j = keys(s).index(k), keys(before).index(k)
        assert s.values[i, 0] == before.values[j, 0]
    t, t_ref = integration_times(out, s), integration_times(ref, s_ref)
    order = np.argsort(s.theta_o_deg)
    order_ref = np.argsort(s_ref.theta_o_deg)
    # the same settings, give or take one rung where a point lies at the limit of one (noise decides)
    assert np.all(np.abs(np.log10(t[order] / t_ref[order_ref])) < 0.6), (t[order], t_ref[order_ref])
    z, _ = zscores(fast, s, t)
    assert np.all(np.abs(z) < 5.0), np.abs(z).max(axis=1)
    # resumed and uninterrupted samples agree within their combined noise
    d = (s.values[order, 0] - s_ref.values[order_ref, 0]) / np.hypot(s.std[order, 0], s_ref.std[order_ref, 0])
    assert np.all(np.abs(d) < 5.0), d
    sc = json.loads((out / "capture.json").read_text())
    assert sc["status"] == "complete" and sc["auto_range"]["ranged_points"] == int(np.sum(t < 0.01))
    dark_keys = set(json.loads((ref / "capture.json").read_text())["auto_range"]["darks"])
    assert set(sc["auto_range"]["darks"]) == dark_keys
