"""Bench files that used to pass ``--check`` and fail later, hang or end in a traceback (issue 11): plans beyond the
axes' resolution or the point limit, numbers that overflow the protocol, garbage tables, files that are not
UTF-8, not readable or not files. Each is one line naming the file and the key, exit status 2, nothing moved."""

from __future__ import annotations

import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from acquisition import Bench, Plan, PlanError
from acquisition.cli import main
from acquisition.plans.planconfig import MAX_PLAN_POINTS
from tests.helpers import unprivileged
from tests.test_acq_support import REPO, make_raw, run_capture, write_config


def check(capsys, cfg: Path) -> tuple[int, str, str]:
    code = main(["--config", str(cfg), "--check"])
    cap = capsys.readouterr()
    return code, cap.out, cap.err


@pytest.mark.parametrize("over, key", [
    ({"plan": {"theta_o_step_deg": 1e-7}}, "[plan].theta_o_step_deg: 1e-07 deg is finer than the detector axis "
                                           "resolution of 0.08789 deg"),
    ({"plan": {"theta_i_deg": None, "theta_i_min_deg": 0.0, "theta_i_max_deg": 80.0, "theta_i_step_deg": 1e-7}},
     "[plan].theta_i_step_deg: 1e-07 deg is finer than the light axis resolution"),
    ({"plan": {"theta_o_step_deg": 1e-3}}, "[plan].theta_o_step_deg: 0.001 deg is finer"),
    ({"plan": {"theta_i_deg": None, "theta_i_min_deg": 0.0, "theta_i_max_deg": 84.0, "theta_i_step_deg": 0.1,
               "theta_o_step_deg": 0.1}}, "[plan].theta_o_step_deg: the plan would have 1.18e+06 points (841 "
                                          f"incidence(s) x 1.4e+03 outgoing angles), more than the {MAX_PLAN_POINTS}"),
    ({"plan": {"adaptive": {"coarse_step_deg": 8.0, "min_step_deg": 0.01}}},
     "[plan.adaptive].min_step_deg: 0.01 deg is finer"),
    ({"plan": {"theta_i_deg": list(np.arange(0.0, 84.0, 0.5)), "theta_o_min_deg": -88.0, "theta_o_max_deg": 88.0,
               "adaptive": {"coarse_step_deg": 8.0, "min_step_deg": 0.1}}},
     "[plan.adaptive].min_step_deg: the refinement could reach"),
])
def test_unbounded_plans_are_config_errors_at_once(tmp_path, capsys, over, key):
    raw = make_raw(over)
    if raw["plan"].get("theta_i_deg") is None:
        raw["plan"].pop("theta_i_deg", None)
    cfg = write_config(tmp_path / "c.toml", raw)
    code, out, err = check(capsys, cfg)  # at once: benchmarks/bench_test_timings.py times these refusals
    assert code == 2 and f"{cfg}: {key}" in err and "nothing was moved" in err, err
    assert out == ""


def test_check_of_the_largest_plan_prints_its_size_and_time(tmp_path):
    """An explicit list of MAX_PLAN_POINTS points (the biggest bench file a plan can be) on the simulated bench,
    whose [simulator] sections `gonio-sim check` validates meanwhile."""
    raw = make_raw()
    del raw["plan"]
    ti = np.repeat(np.arange(0.0, 85.0, 0.5), 200)[:MAX_PLAN_POINTS]
    to = np.tile(np.linspace(-85.0, 85.0, 200), 200)[:MAX_PLAN_POINTS]
    points = ",".join(f"[{a:g},{b:.3f}]" for a, b in zip(ti, to, strict=True))
    cfg = tmp_path / "big.toml"
    cfg.write_text(tomli_w.dumps(raw) + f"\n[plan]\nrepeats = 4\npoints = [{points}]\n")
    r = run_capture("--config", str(cfg), "--check")
    assert r.returncode == 0, r.stderr
    assert f"plan size: {MAX_PLAN_POINTS} points, limit {MAX_PLAN_POINTS}" in r.stdout
    # the total, also in minutes, and what it is made of
    assert "estimated bench time: " in r.stdout and " min)" in r.stdout and "= motion " in r.stdout
    # how fast it is (the README's "about a second") is benchmarks/bench_check.py's figure, not a timed unit test:
    # 0.95-1.1 s on a slow 2-core machine, interpreter start included


def test_python_api_and_scene_plans_are_bounded_too(tmp_path):
    bench = Bench.from_config(write_config(tmp_path / "c.toml", make_raw()))
    with pytest.raises(PlanError, match=r"theta_o step of 1e-07 deg is finer than the detector axis resolution"):
        Plan.grid([30.0], -80.0, 80.0, 1e-7).validate(bench.geometry)
    with pytest.raises(PlanError, match=rf"more than the {MAX_PLAN_POINTS} a plan may hold"):
        Plan.grid(np.arange(0.0, 80.0, 0.2), -80.0, 80.0, 0.1).validate(bench.geometry)
    scene = tmp_path / "fine.toml"
    scene.write_text('[scene]\nname = "fine"\nangular_resolution_deg = 0.001\n')
    with pytest.raises(PlanError, match=r"\(from scene 'fine'\) is finer than the detector axis resolution"):
        bench.plan(scene=scene).validate(bench.geometry)


@pytest.mark.parametrize("motion, over, key", [
    ("serial", {"axes": {"light": {"units_per_deg": 1e300}}}, "[axes.light].units_per_deg: must lie in"),
    ("serial", {"axes": {"light": {"zero_offset": 1e30}}}, "[axes.light].zero_offset: must lie in"),
    ("dynamixel", {"axes": {"light": {"units_per_deg": 1e5}}}, "[axes.light].zero_offset: the soft limits [0, 85] "
                                                               "deg map to positions [2048, 8.50205e+06]"),
    ("dynamixel", {"detector": {"repeats": 1e300}}, "[detector].repeats: must lie in [1, 1000], got 1e+300"),
    ("dynamixel", {"plan": {"repeats": 1e300}}, "[plan].repeats: must lie in [1, 1000], got 1e+300"),
    ("dynamixel", {"simulator": {"aperture_samples": 1e300}}, "[simulator].aperture_samples: no longer read"),
    ("dynamixel", {"simulator": {"electrons_per_count": 1e300}}, "[simulator].electrons_per_count: must lie in"),
    ("dynamixel", {"detector": {"gains": [1.0, 1e300]}}, "[detector].gains: every gain must lie in"),
    ("dynamixel", {"simulator": {"seed": 1e300}}, "[simulator].seed: must lie in [0, 2**63), got 1e+300"),
    ("dynamixel", {"simulator": {"time_scale": 1e-300}}, "[simulator].time_scale: must be 0 (as fast as possible)"),
    ("dynamixel", {"detector": {"type": "spectrometer"}, "simulator": {"spectrometer": {"wl_step_nm": 1e-9}}},
     "[simulator.spectrometer].wl_step_nm: must lie in [0.1, 1000]"),
    ("dynamixel", {"bench": {"serial_timeout_s": 1e300}}, "[bench].serial_timeout_s: must lie in"),
    ("dynamixel", {"calibration": {"mode": "absolute", "source_power": 1e-300, "detector_solid_angle_sr": 1e-3}},
     "[calibration].source_power: must lie in"),
    ("dynamixel", {"material": {"lobes": [{"type": "lambert", "albedo": 1e300}]}},
     "[material].lobes[0].albedo: the lobe reaches f_r = 3.18e+299 1/sr, beyond the physical bound"),
    ("dynamixel", {"material": {"lobes": [{"type": "lambert", "albedo": {
        "wavelengths_nm": list(np.linspace(380.0, 780.0, 5000)), "values": [0.5] * 5000}}]}},
     "[material].lobes: spectra of 5000 wavelengths; at most 4096 are accepted"),
    ("dynamixel", {"material": {"lobes": [{"type": "phong", "exponent": 1e9, "specular": 1.0}]}},
     "[material].lobes[0].exponent/specular: the lobe reaches"),
])
def test_numbers_that_would_overflow_later_are_refused_by_check(tmp_path, capsys, motion, over, key):
    cfg = write_config(tmp_path / "c.toml", make_raw({"bench": {"motion": motion}}, over))
    code, _, err = check(capsys, cfg)
    assert code == 2 and f"{cfg}: {key}" in err and "nothing was moved" in err, err
    assert len(err) < 400 and err.count("\n") == 1, err


@pytest.mark.slow
def test_a_tabulated_lobe_of_garbage_fails_check_and_the_simulator_refuses_to_serve(tmp_path, capsys):
    (tmp_path / "garbage.binary").write_bytes(np.random.default_rng(0).bytes(3000))
    (tmp_path / "wild.binary").write_bytes(np.array([90, 90, 180], "<i4").tobytes()
                                           + np.full(3 * 1_458_000, 4.6e304).astype("<f8").tobytes())
    for name, what in (("garbage.binary", "header says"), ("wild.binary", "4374000 cell(s) (r[0,0,0]")):
        raw = make_raw({"material": {"lobes": [{"type": "tabulated", "path": name}]}})
        cfg = write_config(tmp_path / f"{name}.toml", raw)
        code, _, err = check(capsys, cfg)
        assert code == 2 and f"{cfg}: [material].lobes[0].path: {tmp_path / name}: {what}" in err, err
        assert name == "garbage.binary" or "above 1e+08 1/sr, far beyond any physical BRDF" in err
        r = subprocess.run([sys.executable, "-m", "simulator.cli", "serve", "--config", str(cfg)], cwd=REPO,
                           capture_output=True, text=True, timeout=30)
        assert r.returncode == 2 and r.stdout == "", r  # no ports served
        assert f"[material].lobes[0].path: {tmp_path / name}: {what}" in r.stderr


def test_config_files_that_are_not_utf8_text_or_not_files(tmp_path, capsys):
    bad = tmp_path / "latin1.toml"
    bad.write_bytes((REPO / "configs" / "simulated.toml").read_bytes().replace(b"blue-plastic", b"bleu-\xe9t\xe9"))
    (tmp_path / "dir.toml").mkdir()
    for path, what in ((bad, ": not a UTF-8 text file"), (tmp_path / "dir.toml", ": is a directory"),
                       (Path("/dev/zero"), ": not a regular file")):
        code, _, err = check(capsys, path)  # /dev/zero: refused, never read
        assert code == 2 and f"gonio-capture: {path}" in err and what in err and err.count("\n") == 1, err
    scene = tmp_path / "scene.toml"
    scene.write_bytes(b"name = '\xff'\n")
    assert main(["--config", str(REPO / "configs" / "simulated.toml"), "--check", "--scene", str(scene)]) == 2
    assert f"{scene}: invalid TOML" in capsys.readouterr().err


def test_an_unreadable_config_or_scene_is_one_line_exit_2(tmp_path):
    cfg = tmp_path / "secret.toml"
    shutil.copy(REPO / "configs" / "simulated.toml", cfg)
    cfg.chmod(0o000)
    scene = tmp_path / "scene.toml"
    shutil.copy(REPO / "configs" / "scenes" / "grazing.toml", scene)
    scene.chmod(0o000)
    for args, where in ((["--config", str(cfg), "--check"], cfg),
                        (["--config", str(REPO / "configs" / "simulated.toml"), "--check", "--scene", str(scene)],
                         scene)):
        r = subprocess.run([sys.executable, "-m", "acquisition.cli", *args], cwd=REPO, capture_output=True,
                           text=True, timeout=60, **unprivileged())
        assert r.returncode == 2, r.stderr
        assert f"{where}: cannot read" in r.stderr and "Permission denied" in r.stderr, r.stderr
        assert "Traceback" not in r.stderr and r.stderr.count("\n") == 1
