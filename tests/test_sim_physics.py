"""Bench physics: signal formula, blind spot, saturation, determinism, spectrometer, aperture."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from tests.helpers import deep_merge

NOISELESS = {"simulator": {"read_noise": 0.0, "shot_noise": False, "aperture_samples": 1}}


def bench_from(config_dict, *overs) -> VirtualBench:
    over = NOISELESS
    for o in overs:
        over = deep_merge(over, o)
    return VirtualBench(config_from_dict(config_dict(over)))


def read(bench: VirtualBench, cmd: str) -> dict[str, str]:
    lines = bench.process("serial", (cmd + "\n").encode()).decode().splitlines()
    assert lines[-1] == "ok", lines
    tag, *fields = lines[0].split()
    return dict(f.split("=", 1) for f in fields)


def test_noiseless_reading_equals_formula(config_dict):
    b = bench_from(config_dict)
    ti, to = b.arm_angles()
    assert (ti, to) == (0.0, 45.0)
    from reconstruction.geometry import inplane_to_dirs

    wi, wo = inplane_to_dirs(math.radians(ti), math.radians(to))
    f = float(np.mean(b.physics.material.eval(wi, wo)))
    s = b.cfg.sim
    expected = s.source_power * f * math.cos(math.radians(to)) * s.detector_solid_angle_sr + s.dark_offset
    r = read(b, "READ 3")
    vals = [int(v) for v in r["values"].split(",")]
    assert all(abs(v - expected) <= 0.5 for v in vals)
    assert r["sat"] == "0"


def test_lambertian_analytic(config_dict):
    b = bench_from(config_dict, {"material": {"lobes": [{"type": "lambert", "albedo": 0.5}]}})
    for ti, to in [(0.0, 45.0), (30.0, -60.0), (60.0, 10.0)]:
        expected = 1e6 * 0.5 / math.pi * math.cos(math.radians(to)) * 1e-3 + 200.0
        assert b.physics.expected_reading(ti, to)[0] == pytest.approx(expected)
    # a dark read has no signal
    assert float(read(b, "DARK 2")["mean"]) == 200.0
    # relative calibration: the white reference is a Lambertian of the configured reflectance
    read(b, "SAMPLE REF")
    expected_ref = 1e6 * 0.99 / math.pi * math.cos(math.radians(45)) * 1e-3 + 200.0
    assert abs(float(read(b, "READ 1")["mean"]) - expected_ref) <= 0.5
    assert read(b, "SAMPLE?")["sample"] == "REF"


def test_blind_spot_gives_dark(config_dict):
    b = bench_from(config_dict, {"material": {"lobes": [{"type": "lambert", "albedo": 0.9}]}})
    ph = b.physics
    assert ph.expected_reading(30.0, -28.0)[0] == 200.0           # |ti + to| = 2 < 4: shadowed
    assert ph.expected_reading(30.0, -25.0)[0] > 200.0 + 50.0     # outside the blind spot
    codes, sat = ph.read([30.0, 30.0], [-31.0, -20.0])
    assert codes[0, 0] == 200.0 and codes[1, 0] > 250.0


def test_saturation_clips(config_dict):
    b = bench_from(config_dict, {"simulator": {"source_power": 1e10}})
    r = read(b, "READ 2")
    assert r["values"] == "65535,65535" and r["sat"] == "2"
    b2 = bench_from(config_dict, {"simulator": {"adc_bits": 12}, "detector": {"saturation": 100000}})
    b2.physics.source_power = 1e10
    assert read(b2, "READ 1")["values"] == "4095"


def test_integration_time_and_gain_scale_signal(config_dict):
    b = bench_from(config_dict, {"material": {"lobes": [{"type": "lambert", "albedo": 0.5}]}})
    base = 1e6 * 0.5 / math.pi * math.cos(math.radians(45)) * 1e-3
    assert float(read(b, "READ 1")["mean"]) - 200.0 == pytest.approx(base, abs=0.5)
    read(b, "INT 0.02")
    assert float(read(b, "READ 1")["mean"]) - 200.0 == pytest.approx(2 * base, abs=0.5)
    read(b, "GAIN 3")
    assert float(read(b, "READ 1")["mean"]) - 200.0 == pytest.approx(6 * base, abs=0.5)
    t0 = b.clock.now()
    read(b, "READ 5")
    assert b.clock.now() - t0 == pytest.approx(5 * 0.02)  # integration advances simulated time


def test_deterministic_for_seed(config_dict):
    def run(seed):
        b = VirtualBench(config_from_dict(config_dict({"simulator": {"seed": seed}})))
        return [read(b, cmd)["values"] for cmd in ("READ 8", "DARK 8", "READ 8")]

    assert run(5) == run(5)
    assert run(5) != run(6)


def test_noise_statistics(config_dict):
    b = VirtualBench(config_from_dict(config_dict({"simulator": {"shot_noise": False, "read_noise": 5.0}})))
    codes = np.array([int(v) for v in read(b, "DARK 1000")["values"].split(",")])
    assert abs(codes.mean() - 200.0) < 1.0
    assert 4.5 < codes.std() < 5.5


def test_aperture_averaging_blurs_peak(config_dict):
    spec = {"material": {"lobes": [{"type": "ggx", "alpha": 0.02, "specular": 1.0, "f0": 1.0}]},
            "simulator": {"detector_solid_angle_sr": 0.01}}
    point = bench_from(config_dict, spec)
    wide = bench_from(config_dict, spec, {"simulator": {"aperture_samples": 64}})
    p = point.physics.expected_signal(30.0, 30.0)[0]
    w = wide.physics.expected_signal(30.0, 30.0)[0]
    assert w < 0.5 * p  # the narrow peak is averaged over the aperture
    # a Lambertian is (almost) unaffected
    lam = {"material": {"lobes": [{"type": "lambert", "albedo": 0.5}]}}
    a = bench_from(config_dict, lam).physics.expected_signal(30.0, 20.0)[0]
    b = bench_from(config_dict, lam, {"simulator": {"aperture_samples": 64}}).physics.expected_signal(30.0, 20.0)[0]
    assert b == pytest.approx(a, rel=1e-3)


def test_spectrometer(config_dict):
    b = bench_from(config_dict, {"detector": {"type": "spectrometer"},
                                 "simulator": {"spectrometer": {"wl_min_nm": 400, "wl_max_nm": 700,
                                                                "wl_step_nm": 10}}})
    info = read(b, "DETECTOR?")
    wl = np.array([float(x) for x in info["wavelengths"].split(",")])
    assert info["type"] == "spectrometer" and wl[0] == 400 and wl[-1] == 700 and wl.size == 31
    mean = np.array([float(x) for x in read(b, "READ 2")["mean"].split(",")])
    assert mean.size == 31
    # blue plastic: more signal in the blue than in the red
    assert mean[wl == 450][0] > mean[wl == 650][0] > 200.0
    dark = np.array([float(x) for x in read(b, "DARK 1")["mean"].split(",")])
    assert np.all(dark == 200.0)


def test_config_typos_are_errors(config_dict):
    with pytest.raises(ValueError, match="drop_reply_rat"):
        config_from_dict(config_dict({"simulator": {"faults": {"drop_reply_rat": 0.5}}}))
    with pytest.raises(ValueError, match="motion"):
        config_from_dict(config_dict({"bench": {"motion": "hydraulic"}}))


def test_spectrometer_sees_an_rgb_material_as_spectra_that_convert_back_to_its_rgb(config_dict):
    # an RGB albedo becomes reflectance spectra (Mallett-Yuksel 2019 basis) whose sRGB under D65 is that albedo
    albedo = [0.05, 0.10, 0.40]
    b = bench_from(config_dict, {"detector": {"type": "spectrometer"},
                                 "material": {"lobes": [{"type": "lambert", "albedo": albedo}]}})
    wl = b.physics.detector.wavelengths_nm
    spectra = b.physics.to_detector_channels(np.array([albedo]), b.physics.material)
    assert spectra.shape == (1, wl.size) and np.all(spectra > 0)
    from reconstruction.colour import spectra_to_rgb

    rgb, _ = spectra_to_rgb(spectra, wl)
    np.testing.assert_allclose(rgb[0], albedo, rtol=0.02, atol=1e-3)
    white = b.physics.to_detector_channels(np.array([[1.0, 1.0, 1.0]]), b.physics.material)
    np.testing.assert_allclose(white, 1.0, atol=0.02)  # (1, 1, 1) is a flat reflectance of 1
