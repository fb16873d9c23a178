"""Bench physics: signal formula, blind spot, saturation, determinism, spectrometer, aperture."""

from __future__ import annotations

import math

import numpy as np
import pytest

from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from tests.helpers import deep_merge

NOISELESS = {"simulator": {"read_noise": 0.0, "shot_noise": False, "input_noise": 0.0, "input_offset": 0.0}}


def CONE(omega_sr: float = 1e-3) -> float:
    """A Lambertian's reading over f cos(theta_o) at the cone's centre: the cone's mean cos, 1 - Omega / (4 pi)."""
    return 1.0 - omega_sr / (4.0 * math.pi)


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
    from reconstruction.core.geometry import inplane_to_dirs

    wi, wo = inplane_to_dirs(math.radians(ti), math.radians(to))
    f = b.physics.material.eval(wi, wo)  # alpha 0.15: smooth over the 1e-3 sr cone (cone average = f to 1e-4)
    f_band = float(f @ band_of_rgb())  # the photodiode's band (silicon x halogen-3000K), not the mean of R, G, B
    assert abs(f_band - float(np.mean(f))) > 0.05 * f_band
    s = b.cfg.sim
    expected = s.source_power * f_band * math.cos(math.radians(to)) * 1e-3 + s.dark_offset
    r = read(b, "READ 3")
    vals = [int(v) for v in r["values"].split(",")]
    assert all(abs(v - expected) <= 0.5 for v in vals)
    assert r["sat"] == "0"


def band_of_rgb() -> np.ndarray:
    """(3,) weights of linear-sRGB R, G, B in the silicon x halogen-3000K band: each primary's Mallett-Yuksel
    spectrum (colour-science's own recovery function) weighted by responsivity x Planck(3000 K), over 380-780 nm."""
    import colour

    wl = np.arange(380.0, 781.0, 5.0)
    resp = np.interp(wl, [350, 400, 450, 500, 550, 600, 650, 700, 750, 800], [0.08, 0.12, 0.20, 0.27, 0.32, 0.37,
                                                                              0.41, 0.45, 0.49, 0.53])
    planck = wl ** -5.0 / np.expm1(1.4387769e7 / (wl * 3000.0))
    w = resp * planck / np.sum(resp * planck)
    out = []
    for rgb in np.eye(3):
        sd = colour.recovery.RGB_to_sd_Mallett2019(rgb)
        out.append(float(w @ np.interp(wl, sd.wavelengths, sd.values)))
    return np.array(out)


def test_the_photodiode_band_cancels_for_grey_and_weights_colour(config_dict):
    """A grey sample reads its albedo whatever the band; a blue one less than the mean of its R, G, B under a
    halogen source on silicon (red-heavy), and a D65 source moves it towards blue."""
    grey = bench_from(config_dict, {"material": {"lobes": [{"type": "lambert", "albedo": [0.3, 0.3, 0.3]}]}})
    blue = {"material": {"lobes": [{"type": "lambert", "albedo": [0.05, 0.10, 0.40]}]}}
    halogen = bench_from(config_dict, blue)
    d65 = bench_from(config_dict, blue, {"bench": {"source_spectrum": "D65"}})
    g = grey.physics.f_cos(0.0, 0.0)[0]
    assert g == pytest.approx(0.3 / math.pi * CONE(), rel=1e-5)
    h = halogen.physics.f_cos(0.0, 0.0)[0] * math.pi
    d = d65.physics.f_cos(0.0, 0.0)[0] * math.pi
    assert h == pytest.approx(float(np.array([0.05, 0.10, 0.40]) @ band_of_rgb()), rel=2e-3)
    assert h < 0.8 * np.mean([0.05, 0.10, 0.40]) and d > 1.1 * h


def test_lambertian_analytic(config_dict):
    b = bench_from(config_dict, {"material": {"lobes": [{"type": "lambert", "albedo": 0.5}]}})
    for ti, to in [(0.0, 45.0), (30.0, -60.0), (60.0, 10.0)]:
        expected = 1e6 * 0.5 / math.pi * math.cos(math.radians(to)) * 1e-3 * CONE() + 200.0
        assert b.physics.expected_reading(ti, to)[0] == pytest.approx(expected)
    # a dark read has no signal
    assert float(read(b, "DARK 2")["mean"]) == 200.0
    # relative calibration: the white reference is a Lambertian of the configured reflectance
    read(b, "SAMPLE REF")
    expected_ref = 1e6 * 0.99 / math.pi * math.cos(math.radians(45)) * 1e-3 * CONE() + 200.0
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
    read(b, "GAIN 10")
    assert float(read(b, "READ 1")["mean"]) - 200.0 == pytest.approx(20 * base, abs=0.5)
    assert read(b, "GAIN?")["gain"] == "10"
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


def test_a_mirror_reads_its_reflectance_not_its_peak(config_dict):
    """The reading integrates f cos over the detector's cone: a ggx lobe of alpha 1e-3 (0.06 deg wide) in the 1e-3 sr
    cone gives about the lobe's energy (specular 0.95, no Fresnel), where f at the centre times the cone would be
    ~100 times more; a Lambertian reads f cos theta_o times the cone's mean of cos / cos at its centre,
    (1 + cos a) / 2 = 1 - Omega / (4 pi) exactly."""
    spec = {"material": {"lobes": [{"type": "ggx", "alpha": 1e-3, "specular": 0.95}]}}
    b = bench_from(config_dict, spec)
    s = b.physics.expected_signal(30.0, 30.0)[0]
    assert s == pytest.approx(1e6 * 0.95, rel=0.02)
    from reconstruction.core.geometry import inplane_to_dirs

    wi, wo = inplane_to_dirs(math.radians(30.0), math.radians(30.0))
    point = 1e6 * float(b.physics.material.eval(wi, wo)[0]) * math.cos(math.radians(30.0)) * 1e-3
    assert point > 50 * s
    assert b.physics.expected_signal(30.0, 36.0)[0] < 1e-3 * s  # outside the cone: the diffuse floor only (none)
    lam = {"material": {"lobes": [{"type": "lambert", "albedo": 0.5}]}, "detector": {"solid_angle_sr": 0.01}}
    a = bench_from(config_dict, lam).physics.expected_signal(30.0, 20.0)[0]
    assert a == pytest.approx(1e6 * 0.5 / math.pi * math.cos(math.radians(20.0)) * 0.01 * CONE(0.01), rel=1e-6)


def test_each_gain_has_its_own_offset_and_noise(config_dict):
    """Reading = g (S + input_offset + input_noise) + dark_offset + read_noise: a dark at gain 1e4 sits at 200 + 1e4
    x 0.2 with sqrt(5^2 + (1e4 x 0.003)^2) counts rms; GAIN accepts only the amplifier's gains."""
    b = VirtualBench(config_from_dict(config_dict({"simulator": {"shot_noise": False}})))
    assert read(b, "DETECTOR?")["gains"] == "1,10,100,1000,10000"
    stats = {}
    for g in (1, 10000):
        read(b, f"GAIN {g}")
        codes = np.array([int(v) for v in read(b, "DARK 1000")["values"].split(",")])
        stats[g] = (codes.mean(), codes.std())
    assert stats[1][0] == pytest.approx(200.2, abs=0.5) and stats[1][1] == pytest.approx(5.0, rel=0.1)
    assert stats[10000][0] == pytest.approx(2200.0, abs=3.0)
    assert stats[10000][1] == pytest.approx(math.hypot(5.0, 30.0), rel=0.1)
    assert b.process("serial", b"GAIN 3\n") == b"error:2\n"


def test_the_spot_overfilling_the_sample_loses_light(config_dict):
    """The 10 mm beam lights 10 / cos theta_i mm of the 40 mm sample: at 80 deg 10 / cos 80 = 57.6 mm, and the
    reading falls by the part of the ellipse outside the circle (a Monte Carlo estimate here)."""
    lam = {"material": {"lobes": [{"type": "lambert", "albedo": 0.5}]}}
    b = bench_from(config_dict, lam)
    f = b.physics.expected_signal(80.0, 10.0)[0] / (1e6 * 0.5 / math.pi * math.cos(math.radians(10.0)) * 1e-3 * CONE())
    rng = np.random.default_rng(0)
    u = rng.uniform(-1.0, 1.0, (400_000, 2))
    u = u[(u ** 2).sum(axis=1) < 1.0] * [5.0 / math.cos(math.radians(80.0)), 5.0]
    assert f == pytest.approx(np.mean((u ** 2).sum(axis=1) < 20.0 ** 2), abs=3e-3)
    assert f < 0.85
    assert b.physics.expected_signal(70.0, 10.0)[0] == pytest.approx(
        1e6 * 0.5 / math.pi * math.cos(math.radians(10.0)) * 1e-3 * CONE(), rel=1e-9)  # 10 / cos 70 = 29 mm: all on it


def test_old_simulator_keys(config_dict):
    """[simulator].detector_solid_angle_sr still sets the cone (older files); aperture_samples is refused naming the
    new key, and so is the old key beside the new one."""
    raw = config_dict({"simulator": {"detector_solid_angle_sr": 0.004}})
    del raw["detector"]["solid_angle_sr"]
    assert config_from_dict(raw).detector.solid_angle_sr == 0.004
    with pytest.raises(ValueError, match=r"\[simulator\].aperture_samples: no longer read.*\[detector\]"
                                         r".solid_angle_sr"):
        config_from_dict(config_dict({"simulator": {"aperture_samples": 1}}))
    with pytest.raises(ValueError, match=r"\[simulator\].detector_solid_angle_sr: the detector's acceptance is "
                                         r"\[detector\].solid_angle_sr now"):
        config_from_dict(config_dict({"simulator": {"detector_solid_angle_sr": 0.004}}))


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
    from reconstruction.core.colour import spectra_to_rgb

    rgb, _ = spectra_to_rgb(spectra, wl)
    np.testing.assert_allclose(rgb[0], albedo, rtol=0.02, atol=1e-3)
    white = b.physics.to_detector_channels(np.array([[1.0, 1.0, 1.0]]), b.physics.material)
    np.testing.assert_allclose(white, 1.0, atol=0.02)  # (1, 1, 1) is a flat reflectance of 1
