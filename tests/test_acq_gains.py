"""Dynamic range with the shipped simulated bench (configs/simulated.toml): the photodiode amplifier's gains and
the integration time, auto-ranged, capture a black felt and a mirror with the same config; a reading in the noise
floor keeps its honest standard deviation; saturation that no setting avoids names the point; the footprint at
grazing incidence is lost by the bench and corrected by the calibration. Few points per capture (hardware in the
loop through the simulator's pseudo-terminals)."""

from __future__ import annotations

import json
import math

import numpy as np

from acquisition.cli import main
from tests.test_acq_support import ground_truth, make_raw, read, write_config, zscores

FELT = {"name": "black-felt", "lobes": [{"type": "lambert", "albedo": 0.01}]}
MIRROR = {"name": "mirror", "lobes": [{"type": "lambert", "albedo": 0.02},
                                      {"type": "ggx", "alpha": 1e-3, "specular": [0.97, 0.95, 0.9]}]}


def capture(tmp_path, name, material, points, over=None, code=0, capsys=None):
    raw = make_raw({"plan": {"points": points}}, over or {})
    raw["plan"].pop("theta_i_deg")
    raw["plan"].pop("theta_o_min_deg"), raw["plan"].pop("theta_o_max_deg"), raw["plan"].pop("theta_o_step_deg")
    raw["material"] = material
    cfg = write_config(tmp_path / f"{name}.toml", raw)
    out = tmp_path / name
    got = main(["--config", str(cfg), "--out", str(out), "--no-progress"])
    err = capsys.readouterr().err if capsys is not None else ""
    assert got == code, err
    return raw, out, err


def floor_f_cos(s) -> float:
    """The noise floor in f_r cos(theta_o) (1/sr): the dark's noise at the reference setting (the highest gain,
    the configured integration time), as the standard deviation of the mean of one point's repeats, through the
    slice's calibration."""
    cal = s.meta["calibration"]
    net = cal["reference_reading"]["mean"][0] - cal["dark"]["mean"][0]
    k = cal["rho_ref"][0] / math.pi * math.cos(math.radians(cal["reference_theta_o_deg"])) / net
    return cal["dark"]["std"][0] / math.sqrt(float(np.min(s.repeats))) * k


def test_black_felt_and_mirror_with_the_same_config_span_1e8(tmp_path, capsys):
    raw_f, out_f, _ = capture(tmp_path, "felt", FELT, [[30.0, -70.0], [30.0, 0.0], [30.0, 70.0]], capsys=capsys)
    raw_m, out_m, err = capture(tmp_path, "mirror", MIRROR, [[30.0, 29.0], [30.0, 30.0], [30.0, 31.0]],
                                capsys=capsys)
    felt, mirror = read(out_f / "slice.csv"), read(out_m / "slice.csv")
    for raw, s in ((raw_f, felt), (raw_m, mirror)):
        z, _ = zscores(raw, s)
        assert np.all(np.abs(z) < 5.0), (s.meta["material"], z.ravel())
    # the felt is read at high gain, the mirror's peak at the lowest gain and a shorter integration time
    rec_f = json.loads((out_f / "capture.json").read_text())["auto_range"]
    assert max(rec_f["ladder_gains"]) == 10000.0  # points not listed were read at the reference, gain 1e4
    assert all(g >= 1000.0 for g in rec_f["point_gains"].values()), rec_f["point_gains"]
    rec_m = json.loads((out_m / "capture.json").read_text())["auto_range"]
    assert rec_m["point_gains"]["30.0,30.0"] == 1.0 and rec_m["points"]["30.0,30.0"] < 0.01
    # a mirror reads its reflectance: f cos over the cone's solid angle is the lobe's energy in the band
    peak = int(np.argmax(mirror.values[:, 0]))
    f_cos = mirror.values[peak, 0] * math.cos(math.radians(mirror.theta_o_deg[peak]))
    assert f_cos * 1e-3 == np.clip(f_cos * 1e-3, 0.9, 0.96)
    assert mirror.values[peak, 0] == np.clip(mirror.values[peak, 0], *(ground_truth(raw_m, mirror)[peak, 0] *
                                                                        np.array([0.99, 1.01])))
    dr = f_cos / floor_f_cos(felt)
    assert dr >= 1e8, f"dynamic range {dr:.3g}"
    assert "auto-ranged" in err


def test_a_reading_in_the_noise_floor_keeps_its_honest_std(tmp_path, capsys):
    """A sample 100 times darker than the felt at 70 deg reads about the floor: values scatter about the truth
    (some below zero, none clipped), each with the floor's standard deviation."""
    ink = {"name": "black-ink", "lobes": [{"type": "lambert", "albedo": 2e-7}]}
    pts = [[30.0, float(x)] for x in (-70, -60, -50, -40, -20, 0, 20, 40, 60, 70)]
    raw, out, _ = capture(tmp_path, "ink", ink, pts, capsys=capsys)
    s = read(out / "slice.csv")
    z, _ = zscores(raw, s)
    assert np.all(np.abs(z) < 5.0), z.ravel()
    truth = ground_truth(raw, s)[:, 0]
    assert np.all(s.std[:, 0] > 0.3 * truth.max())  # the floor, not a relative error of a value
    f_cos_std = s.std[:, 0] * np.cos(np.radians(s.theta_o_deg))
    # the floor's std (dark noise at 1e4): a std of 4 repeats scatters as sqrt(chi2_3 / 3) (above 1.6 x in 5 % of
    # samples, above 2.6 x in 1e-4): the median close to it, every sample within those bounds
    floor = floor_f_cos(s)
    assert abs(np.median(f_cos_std) / floor - 1.0) < 0.3
    assert np.all((f_cos_std > 0.2 * floor) & (f_cos_std < 2.6 * floor))
    assert np.any(s.values[:, 0] < 0.0) or np.all(np.abs(z) < 3.0)


def test_saturation_no_setting_avoids_names_the_point(tmp_path, capsys):
    _, _, err = capture(tmp_path, "bright", MIRROR, [[30.0, 20.0], [30.0, 30.0]],
                        {"simulator": {"source_power": 1e11}}, code=1, capsys=capsys)
    assert "point (30, 30): the detector saturates (65535 counts) even at the lowest gain (1) and the shortest " \
           "integration time, [detector].min_integration_time_s = 1e-05 s" in err, err


def test_footprint_lost_at_grazing_is_corrected(tmp_path, capsys):
    """A 10 mm beam on a 20 mm sample overfills it beyond 60 deg: at 80 deg 42 % of the light falls on it. The
    bench loses the rest; the calibration corrects it (the values match the material), and says so."""
    grey = {"name": "grey", "lobes": [{"type": "lambert", "albedo": 0.5}]}
    over = {"bench": {"sample_diameter_mm": 20.0}}
    raw, out, _ = capture(tmp_path, "grazing", grey, [[20.0, 30.0], [80.0, 30.0], [80.0, 50.0]], over,
                          capsys=capsys)
    s = read(out / "slice.csv")
    z, rel = zscores(raw, s)
    assert np.all(np.abs(z) < 5.0) and np.all(np.abs(rel) < 0.01), (z.ravel(), rel.ravel())
    fp = s.meta["calibration"]["footprint"]
    assert fp["corrected_theta_i_deg"] == [80.0] and 0.40 < fp["fraction_on_sample"]["80"] < 0.43
    assert s.meta["instrument"] == {"detector_solid_angle_sr": 1e-3, "source_divergence_deg": 0.25,
                                    "beam_diameter_mm": 10.0, "sample_diameter_mm": 20.0,
                                    "band": "silicon x halogen-3000K"}
    cfg = write_config(tmp_path / "check.toml", raw)
    assert main(["--config", str(cfg), "--check"]) == 0
    out_text = capsys.readouterr().out
    assert "warning: footprint: the 10 mm beam overfills the 20 mm sample beyond theta_i = 60.0 deg" in out_text
    assert "incidence(s) 80 deg (58 % lost)" in out_text
