"""Hardware in the loop on the simulator: full captures through the pseudo-terminals of `gonio-sim serve`
(real dynamixel_sdk, real pyserial), compared with the ground truth of the config's [material]."""

from __future__ import annotations

import json

import numpy as np
import pytest

from acquisition import Bench, Plan
from acquisition.cli import main
from tests.test_acq_support import REPO, keys, make_raw, read, run_capture, write_config, zscores


def _check_against_truth(raw, s, z_max=5.0):
    z, rel = zscores(raw, s)
    chi2 = float(np.mean(z ** 2))
    assert np.all(np.abs(z) < z_max), (np.abs(z).max(), s.theta_o_deg[np.argmax(np.abs(z).max(axis=1))])
    assert 0.3 < chi2 < 2.5, chi2
    return z, rel


@pytest.mark.slow
@pytest.mark.parametrize("motion", ["dynamixel", "serial"])
def test_full_capture_matches_ground_truth(tmp_path, capsys, motion):
    raw = make_raw({"bench": {"motion": motion}})
    cfg = write_config(tmp_path / f"{motion}.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "captured 26 new sample(s)" in err and "simulated capture time" in err
    s = read(out / "slice.csv")
    bench = Bench.from_config(cfg)
    chk = bench.check(bench.plan())
    assert sorted(keys(s)) == sorted((ti, to) for ti, to in chk.measurable)
    assert len(chk.unmeasurable) == 3  # -35, -30, -25: around the retro direction of theta_i = 30
    assert s.meta["quantity"] == "brdf" and s.meta["material"] == "blue-plastic"
    assert s.channels == ["value"] and np.all(s.repeats == 4)
    z, rel = _check_against_truth(raw, s)
    assert abs(float(np.median(rel))) < 0.05
    sidecar = json.loads((out / "capture.json").read_text())
    run = sidecar["runs"][-1]
    assert sidecar["status"] == "complete" and run["bench_clock"] == "controller"
    assert run["bench_time_s"] > run["motion_s"] > 0 and len(sidecar["unmeasurable"]) == 3
    log = (out / "capture.log").read_text()
    assert "not measurable: (30, -30): collision" in log and "motion released (torque off)" in log


def test_spectrometer_with_reference_spectrum_on_stepper_bench(tmp_path, capsys):
    (tmp_path / "panel.csv").write_text("wavelength_nm,reflectance\n380,0.95\n580,0.99\n780,0.97\n")
    raw = make_raw({"bench": {"motion": "serial"}, "detector": {"type": "spectrometer"},
                    "simulator": {"spectrometer": {"wl_min_nm": 400.0, "wl_max_nm": 700.0, "wl_step_nm": 20.0}},
                    "plan": {"theta_o_step_deg": 10.0}})
    del raw["calibration"]["reference_reflectance"]
    raw["calibration"]["reference_spectrum"] = "panel.csv"
    cfg = write_config(tmp_path / "spec.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    s = read(out / "slice.csv")
    assert s.kind == "spectral" and s.channels[0] == "400nm" and len(s.channels) == 16
    np.testing.assert_allclose(s.meta["calibration"]["rho_ref"][:2], [0.95 + 0.04 * 20 / 200, 0.95 + 0.04 * 40 / 200])
    _check_against_truth(raw, s)


def test_absolute_calibration(tmp_path, capsys):
    raw = make_raw({"calibration": {"mode": "absolute", "source_power": 1.0e6, "detector_solid_angle_sr": 1.0e-3},
                    "plan": {"theta_o_step_deg": 10.0}})
    cfg = write_config(tmp_path / "abs.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    s = read(out / "slice.csv")
    assert s.meta["calibration"]["mode"] == "absolute" and "reference_reading" not in s.meta["calibration"]
    _check_against_truth(raw, s)


def test_python_api_and_plan_ordering(tmp_path):
    """Bench.from_config / bench.capture(plan) with several incidences; motion time beats the naive order."""
    raw = make_raw({"bench": {"motion": "serial"}})
    cfg = write_config(tmp_path / "api.toml", raw)
    plan = Plan.grid([20.0, 50.0], -60.0, 60.0, 10.0, repeats=2)
    with Bench.from_config(cfg) as bench:
        ti, to = bench.positions()
        assert (round(ti, 3), round(to, 3)) == (0.0, 45.0)  # parked
        result = bench.capture(plan, out=tmp_path / "run", progress=False)
        assert bench.is_open  # the caller's bench stays open
        rd = bench.read(3)
        assert rd.n == 3 and rd.mean.shape == (1,)
    assert result.ok and result.samples_new == 24 and result.status == "complete"
    assert result.plan_motion_estimate_s < result.naive_motion_estimate_s
    # measured stepper motion ~ the estimate plus the simulator's mechanical settling per move
    assert result.motion_s == pytest.approx(result.plan_motion_estimate_s + 0.05 * 25, rel=0.15)
    s = read(tmp_path / "run" / "slice.csv")
    assert len(s) == 24 and np.all(s.repeats == 2)
    _check_against_truth(raw, s)


def test_adaptive_plan_refines_the_specular_peak(tmp_path, capsys):
    raw = make_raw({"plan": {"theta_o_min_deg": -80.0, "theta_o_max_deg": 80.0,
                             "adaptive": {"coarse_step_deg": 8.0, "min_step_deg": 1.0, "tolerance": 0.05}},
                    "simulator": {"source_power": 2.0e7}})  # refinement needs noise below the tolerance
    cfg = write_config(tmp_path / "adaptive.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    s = read(out / "slice.csv")
    to = np.sort(s.theta_o_deg)
    coarse = set(np.arange(-80.0, 81.0, 8.0))
    extra = [x for x in to if x not in coarse]
    assert len(extra) >= 6
    # refinement goes where the slice changes fast: the specular lobe around theta_o = 30 (flat elsewhere)
    assert all(0.0 <= x <= 60.0 for x in extra), extra
    assert np.min(np.diff(to)) >= 1.0 - 1e-9
    _check_against_truth(raw, s)
    # resuming a complete adaptive capture measures nothing more
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0
    assert len(read(out / "slice.csv")) == len(s)


def test_out_dir_with_capture_needs_resume(tmp_path, capsys):
    cfg = write_config(tmp_path / "c.toml", make_raw({"plan": {"theta_o_step_deg": 20.0}}))
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    capsys.readouterr()
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 2
    assert "--resume" in capsys.readouterr().err
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0
    assert "already complete" in capsys.readouterr().err
    # a different plan in the same directory is refused before anything moves
    cfg2 = write_config(tmp_path / "c2.toml", make_raw({"plan": {"theta_o_step_deg": 10.0}}))
    assert main(["--config", str(cfg2), "--out", str(out), "--resume", "--no-progress"]) == 2
    assert "different plan" in capsys.readouterr().err


@pytest.mark.slow
def test_example_script_runs(tmp_path):
    import subprocess
    import sys

    cfg = write_config(tmp_path / "ex.toml", make_raw({"plan": {"theta_o_step_deg": 20.0}}))
    p = subprocess.run([sys.executable, str(REPO / "examples" / "capture_script.py"), str(cfg), str(tmp_path / "o")],
                       capture_output=True, text=True, timeout=60, cwd=REPO)
    assert p.returncode == 0, p.stderr
    assert "samples" in p.stdout
    # the specular reading of the demo material is auto-ranged, not clipped at the saturation (65535 counts)
    line = next(ln for ln in p.stdout.splitlines() if ln.startswith("specular reading"))
    assert "(0 of 4 repeats saturated)" in line and float(line.split()[2]) > 65535.0, line


@pytest.mark.slow
def test_bench_read_ranges_a_saturated_reading_or_warns_without_auto_ranging(tmp_path):
    """The README's Bench snippet at the demo material's specular peak, (30, 30), which saturates the reference
    setting (gain 10000, 0.01 s): with auto-ranging the reading is taken at a lower gain and converted to the
    reference setting (above the saturation, none clipped), as a capture's; the detector is left at the reference
    setting (a dark reads the reference's dark level); without auto-ranging (the lowest gain then, and a source
    1000 x brighter so that it still clips) the clipped reading comes with a SaturationWarning."""
    import warnings

    from acquisition import SaturationWarning

    cfg = write_config(tmp_path / "b.toml", make_raw())
    with Bench.from_config(cfg) as bench, warnings.catch_warnings():
        warnings.simplefilter("error", SaturationWarning)
        dark = bench.dark()
        bench.move(30.0, 30.0)
        bench.settle()
        first, again = bench.read(4), bench.read(4)
        assert first.saturated == again.saturated == 0 and first.n == 4
        assert first.mean[0] > 20 * bench.cfg.detector.saturation  # converted to gain 10000: far above the clip
        assert again.mean[0] == pytest.approx(first.mean[0], rel=0.02)
        assert bench.dark().mean[0] == pytest.approx(dark.mean[0], abs=5 * dark.std[0])  # back at the reference
    cfg = write_config(tmp_path / "n.toml", make_raw({"detector": {"auto_range": False},  # gain 1: 1e3 x the light
                                                       "simulator": {"source_power": 1e9}}))
    with Bench.from_config(cfg) as bench:
        bench.move(30.0, 30.0)
        bench.settle()
        with pytest.warns(SaturationWarning, match=r"Bench.read: 4 of 4 repeats saturated at 65535 counts"):
            clipped = bench.read(4)
        assert clipped.saturated == 4


@pytest.mark.slow
def test_cli_subprocess_json(tmp_path):
    cfg = write_config(tmp_path / "j.toml", make_raw({"plan": {"theta_o_step_deg": 20.0}}))
    p = run_capture("--config", str(cfg), "--out", str(tmp_path / "o"), "--json")
    assert p.returncode == 0, p.stderr
    d = json.loads(p.stdout)
    assert d["status"] == "complete" and d["samples_new"] == d["points_planned"] == 7


@pytest.mark.slow
def test_scene_restricts_the_capture(tmp_path, capsys):
    raw = make_raw({"plan": {"theta_i_deg": [30.0, 60.0]}})
    cfg = write_config(tmp_path / "scene.toml", raw)
    out = tmp_path / "out"
    scene = REPO / "configs" / "scenes" / "grazing.toml"
    assert main(["--config", str(cfg), "--out", str(out), "--scene", str(scene), "--no-progress"]) == 0
    s = read(out / "slice.csv")
    assert set(s.theta_i_deg) == {60.0}
    assert np.all((np.abs(s.theta_o_deg) >= 40.0) & (np.abs(s.theta_o_deg) <= 70.0))
    # |theta_o| in 40..70 on both sides at 1 deg; the retro side loses the collision zone around -60
    assert len(s) + len(s.meta["unmeasurable"]) == 2 * 31 and s.meta["plan"]["scene"] == "grazing"
    glossy = REPO / "configs" / "scenes" / "glossy-product.toml"
    assert main(["--config", str(cfg), "--out", str(tmp_path / "o2"), "--scene", str(glossy), "--check"]) == 0
    assert main(["--config", str(cfg), "--out", str(tmp_path / "o3"), "--scene", str(tmp_path / "none.toml")]) == 2
    assert "no such scene file" in capsys.readouterr().err
