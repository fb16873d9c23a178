"""Bench files: shipped configs load; bad configs give clear errors naming file and key, before any motion."""

from __future__ import annotations

import sys

import pytest
import tomli_w

from acquisition import ConfigError, load_config
from acquisition.cli import main
from acquisition.config import config_from_dict

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

from tests.test_acq_support import REPO, make_raw, write_config


@pytest.mark.parametrize("name", ["simulated.toml", "dynamixel-bench.toml", "serial-bench.toml"])
def test_shipped_configs_load(name):
    cfg = load_config(REPO / "configs" / name)
    assert cfg.bench.transport in ("simulated", "dynamixel", "serial")
    assert {"light", "detector"} <= set(cfg.axes)


def test_auto_range_defaults_and_shipped_settings():
    raw = make_raw()
    for k in ("auto_range", "min_integration_time_s"):
        raw["detector"].pop(k, None)
    d = config_from_dict(raw).detector
    assert d.auto_range is True and d.min_integration_time_s == 1e-5
    d = config_from_dict(make_raw({"detector": {"auto_range": False, "min_integration_time_s": 1e-3}})).detector
    assert d.auto_range is False and d.min_integration_time_s == 1e-3
    for name in ("simulated.toml", "dynamixel-bench.toml", "serial-bench.toml"):
        d = load_config(REPO / "configs" / name).detector
        assert d.auto_range is True and d.min_integration_time_s <= d.integration_time_s


def test_simulated_config_roundtrips_through_tomli_w():
    raw = make_raw(fast=False)
    assert tomllib.loads(tomli_w.dumps(raw)) == raw


def _err(raw, path="bench.toml") -> str:
    with pytest.raises(ConfigError) as ei:
        config_from_dict(raw, path)
    return str(ei.value)


def _drop(raw, section, key):
    d = raw
    for part in section.split("."):
        d = d[part]
    del d[key]
    return raw


@pytest.mark.parametrize("over, where, what", [
    ({"bench": {"transprt": "serial"}}, "[bench].transprt", "did you mean 'transport'"),
    ({"motion": {"tolerance": 0.1}}, "[motion].tolerance", "unknown key"),
    ({"bench": {"transport": "usb"}}, "[bench].transport", "expected one of"),
    ({"axes": {"light": {"max_deg": "high"}}}, "[axes.light].max_deg", "expected a number"),
    ({"axes": {"light": {"min_deg": 50.0, "max_deg": 40.0}}}, "[axes.light].max_deg", "greater than min_deg"),
    ({"axes": {"light": {"park_deg": 86.0}}}, "[axes.light].park_deg", "outside the soft limits"),
    ({"axes": {"light": {"direction": 2}}}, "[axes.light].direction", "expected one of"),
    ({"axes": {"light": {"units_per_deg": 0.0}}}, "[axes.light].units_per_deg", "must be > 0"),
    ({"axes": {"detector": {"max_deg": 120.0, "min_deg": -80.0}}}, "[axes.detector].max_deg", "[-90, 90]"),
    ({"axes": {"light": {"zero_offset": 3900}}}, "[axes.light].zero_offset", "0..4095"),
    ({"axes": {"light": {"model": "AX-12"}}}, "[axes.light].model", "unknown Dynamixel model"),
    ({"axes": {"detector": {"id": 1}}}, "[axes.detector].id", "already the id of [axes.light]"),
    ({"axes": {"turret": {"id": 5}}}, "[axes.turret]", "unknown axis"),
    ({"motion": {"retries": -1}}, "[motion].retries", "must lie in"),
    ({"motion": {"settle_s": True}}, "[motion].settle_s", "expected a number"),
    ({"detector": {"type": "camera"}}, "[detector].type", "expected one of"),
    ({"detector": {"repeats": 0}}, "[detector].repeats", "must lie in"),
    ({"detector": {"auto_range": "yes"}}, "[detector].auto_range", "expected true or false"),
    ({"detector": {"min_integration_time_s": 1e-6}}, "[detector].min_integration_time_s", "must lie in [1e-05, 10]"),
    ({"detector": {"min_integration_time_s": 0.02}}, "[detector].min_integration_time_s",
     "longer than integration_time_s = 0.01 s"),
    ({"detector": {"max_integration_time_s": 1.0}}, "[detector].max_integration_time_s", "did you mean"),
    ({"calibration": {"mode": "absolute"}}, "[calibration].source_power", "missing key"),
    ({"detector": {"monitor": True}, "calibration": {"mode": "absolute", "source_power": 1e6,
                                                    "detector_solid_angle_sr": 1e-3}},
     "[detector].monitor", "ratio readings need [calibration].mode = \"relative\""),
    ({"detector": {"monitor": True, "type": "pm100"}}, "[detector].monitor", "the detector board"),
    ({"calibration": {"reference_reflectance": 1.9}}, "[calibration].reference_reflectance", "(0, 1.5]"),
    ({"calibration": {"reference_theta_o_deg": -2.0}}, "[calibration].reference_theta_o_deg", "collision"),
    ({"calibration": {"reference_spectrum": "nope.csv"}}, "[calibration].reference_spectrum", "cannot read"),
    ({"plan": {"theta_o_step_deg": -1.0}}, "[plan].theta_o_step_deg", "must be > 0"),
    ({"plan": {"theta_o_min_deg": 10.0, "theta_o_max_deg": 0.0}}, "[plan].theta_o_max_deg", "less than"),
    ({"plan": {"theta_i_deg": ["thirty"]}}, "[plan].theta_i_deg", "list of numbers"),
    ({"plan": {"order": "random"}}, "[plan].order", "expected one of"),
    ({"plan": {"adaptive": {"tolerance": 0.1, "coarse": 3}}}, "[plan.adaptive].coarse", "unknown key"),
    ({"material": {"lobes": [{"type": "lambert", "albedo": -1.0}]}}, "[material]", "albedo"),
    ({"extra": {"x": 1}}, "[extra]", "unknown section"),
])
def test_bad_config_names_file_and_key(over, where, what):
    msg = _err(make_raw(over))
    assert msg.startswith("bench.toml: "), msg
    assert where in msg and what in msg, msg


@pytest.mark.parametrize("section, key", [("bench", "transport"), ("axes.light", "max_deg"),
                                          ("motion", "tolerance_deg"), ("detector", "type"),
                                          ("calibration", "mode"), ("plan", "theta_o_step_deg")])
def test_missing_key_is_named(section, key):
    msg = _err(_drop(make_raw(), section, key))
    assert f"[{section}].{key}: missing" in msg, msg


def test_missing_section_and_material():
    raw = make_raw()
    del raw["motion"]
    assert "[motion]: missing section" in _err(raw)
    raw = make_raw()
    del raw["material"]
    assert "[material]: missing section" in _err(raw)


def test_hardware_benches_need_ports():
    raw = make_raw({"bench": {"transport": "dynamixel", "dynamixel_port": "", "serial_port": "/dev/ttyACM0"}})
    del raw["bench"]["motion"]
    assert "[bench].dynamixel_port: missing" in _err(raw)
    raw = make_raw({"bench": {"transport": "serial", "motion": "dynamixel", "serial_port": "/dev/x"}})
    assert "[bench].motion" in _err(raw)


def test_reference_spectrum_file(tmp_path):
    (tmp_path / "panel.csv").write_text("wavelength_nm,reflectance\n400,0.97\n700,0.99\n")
    raw = make_raw()
    del raw["calibration"]["reference_reflectance"]
    raw["calibration"]["reference_spectrum"] = "panel.csv"
    cfg = config_from_dict(raw, tmp_path / "b.toml")
    assert cfg.calibration.reference_spectrum == ((400.0, 700.0), (0.97, 0.99))
    (tmp_path / "bad.csv").write_text("400,0.97\n380,2.0\n")
    raw["calibration"]["reference_spectrum"] = "bad.csv"
    assert "bad.csv:2" in _err(raw, tmp_path / "b.toml")


def test_cli_bad_config_exits_2_before_anything(tmp_path, capsys):
    cfg = write_config(tmp_path / "bad.toml", make_raw({"motion": {"tolerance_deg": "fine"}}))
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"{cfg}: [motion].tolerance_deg: expected a number" in err and "nothing was moved" in err
    assert not out.exists()  # no simulator started, nothing written


def test_cli_missing_file_and_bad_toml(tmp_path, capsys):
    assert main(["--config", str(tmp_path / "nope.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "no such file" in capsys.readouterr().err
    (tmp_path / "broken.toml").write_text("[bench\nname=1")
    assert main(["--config", str(tmp_path / "broken.toml"), "--out", str(tmp_path / "o")]) == 2
    assert "invalid TOML" in capsys.readouterr().err


def test_cli_unreachable_points_exit_2_before_motion(tmp_path, capsys):
    cfg = write_config(tmp_path / "far.toml", make_raw({"plan": {"theta_i_deg": [30.0, 87.0]}}))
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cannot be measured" in err and "(87, -70): theta_i 87 outside the light arm soft limits [0, 85]" in err
    assert not out.exists()


def test_cli_strict_plan_rejects_blind_spot(tmp_path, capsys):
    cfg = write_config(tmp_path / "strict.toml", make_raw({"plan": {"strict": True}}))
    assert main(["--config", str(cfg), "--out", str(tmp_path / "o"), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "(30, -30): collision" in err


def test_cli_check_lists_unmeasurable_points(tmp_path, capsys):
    assert main(["--config", str(REPO / "configs" / "simulated.toml"), "--check"]) == 0
    out = capsys.readouterr().out
    assert "not measurable" in out and "theta_i 40, theta_o -46 to -34 (7 points): collision" in out, out
    assert "naive order" in out


@pytest.mark.parametrize("over, where, what", [
    ({"simulator": {"settle_time_s": "abc"}}, "[simulator].settle_time_s", 'expected a number, got "abc"'),
    ({"simulator": {"settle_tme_s": 0.1}}, "[simulator].settle_tme_s", "unknown key; did you mean 'settle_time_s'"),
    ({"simulator": {"faults": {"drop_reply_rate": 2.0}}}, "[simulator.faults].drop_reply_rate", "must lie in [0, 1]"),
])
def test_cli_bad_simulator_section_exits_2_with_the_simulators_message(tmp_path, capsys, over, where, what):
    """gonio-capture validates [simulator*] through `gonio-sim check` (--check) or the simulator's exit status 2
    (capture): exit 2, the message names file and key, no resume hint."""
    cfg = write_config(tmp_path / "bad.toml", make_raw(over))
    assert main(["--config", str(cfg), "--check"]) == 2
    err = capsys.readouterr().err
    assert f"gonio-capture: {cfg}: {where}: {what}" in err and "nothing was moved" in err, err
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"gonio-capture: {cfg}: {where}: {what}" in err and "nothing was moved" in err, err
    assert "Resume with" not in err and "bench failure" not in err and "exited with status" not in err, err
    assert not (out / "slice.csv").exists()
    assert f"{where}: {what}" in (out / "capture.log").read_text()


def test_cli_check_runs_the_simulator_check_only_for_simulated_benches(tmp_path, capsys):
    assert main(["--config", str(REPO / "configs" / "simulated.toml"), "--check"]) == 0
    raw = tomllib.loads((REPO / "configs" / "dynamixel-bench.toml").read_text())
    raw["simulator"] = {"settle_time_s": "abc"}  # not read on a hardware bench: gonio-sim is not involved
    cfg = write_config(tmp_path / "hw.toml", raw)
    assert main(["--config", str(cfg), "--check"]) == 0, capsys.readouterr().err


@pytest.mark.parametrize("rel", ["afile", "afile/sub"])
def test_cli_out_that_is_a_file_exits_2_with_one_line(tmp_path, capsys, rel):
    (tmp_path / "afile").write_text("x")
    out = tmp_path / rel
    cfg = write_config(tmp_path / "c.toml", make_raw())
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith(f"gonio-capture: --out {out}: ") and "is a file" in err, err
    assert "Traceback" not in err


def test_out_dir_that_cannot_be_created_is_a_plan_error(tmp_path):
    """Through the Python API the engine refuses the directory before anything is opened."""
    from acquisition import Bench, PlanError

    (tmp_path / "afile").write_text("x")
    bench = Bench.from_config(write_config(tmp_path / "c.toml", make_raw()))
    with pytest.raises(PlanError, match=r"afile: is a file, not a directory"):
        bench.capture(out=tmp_path / "afile", progress=False)
    assert not bench.is_open


def test_commented_adaptive_example_is_valid_when_uncommented():
    """configs/simulated.toml shows [plan.adaptive] commented out; uncommenting it must give a valid config."""
    lines = (REPO / "configs" / "simulated.toml").read_text().splitlines()
    k = next(i for i, ln in enumerate(lines) if ln.startswith("# [plan.adaptive]"))
    lines[k] = lines[k][2:]
    k += 1
    while lines[k].startswith("# ") and " = " in lines[k]:
        lines[k] = lines[k][2:]
        k += 1
    cfg = config_from_dict(tomllib.loads("\n".join(lines)), REPO / "configs" / "simulated.toml")
    a = cfg.plan.adaptive
    assert a is not None and a.coarse_step_deg == 8.0 and a.min_step_deg == 1.0 and a.tolerance == 0.05


def test_simulator_that_fails_to_start_reports_its_stderr_from_the_log(tmp_path):
    """The child's stderr goes to the log file (appended to); a start failure quotes this child's part of it."""
    from acquisition import CommError, SimulatorProcess

    fake = tmp_path / "fake-sim"
    fake.write_text("#!/bin/sh\necho 'fake-sim: the bench is on fire' >&2\nexit 1\n")
    fake.chmod(0o755)
    log = tmp_path / "simulator.log"
    log.write_text("an earlier run's log\n")
    sp = SimulatorProcess(REPO / "configs" / "simulated.toml", command=str(fake), log_path=log)
    with pytest.raises(CommError) as ei:
        sp.start()
    msg = str(ei.value)
    assert "exited with status 1: fake-sim: the bench is on fire" in msg and "earlier run" not in msg, msg
    sp.stop()
    assert log.read_text() == "an earlier run's log\nfake-sim: the bench is on fire\n"
    fake.write_text("#!/bin/sh\necho 'gonio-sim: x.toml: [simulator].seed: expected an integer' >&2\nexit 2\n")
    sp = SimulatorProcess(REPO / "configs" / "simulated.toml", command=str(fake), log_path=log)
    with pytest.raises(ConfigError, match=r"^x\.toml: \[simulator\]\.seed: expected an integer$"):
        sp.start()
    sp.stop()


@pytest.mark.parametrize("over, where, what", [
    ({"detector": {"aperture_half_angle_deg": 1.0}}, "[detector].aperture_half_angle_deg",
     "give either solid_angle_sr or aperture_half_angle_deg, not both"),
    ({"detector": {"solid_angle_sr": 0.6}}, "[detector].solid_angle_sr", "must lie in [0, 0.5]"),
    ({"detector": {"responsivity": "germanium"}}, "[detector].responsivity",
     "unknown responsivity 'germanium'; expected \"silicon\" or a path"),
    ({"bench": {"source_spectrum": "halogen-hot"}}, "[bench].source_spectrum", "unknown source 'halogen-hot'"),
    ({"detector": {"gains": [1.0, 1.0]}}, "[detector].gains", "gains must differ"),
    ({"detector": {"gains": []}}, "[detector].gains", "expected a non-empty list of numbers"),
    ({"bench": {"source_divergence_deg": 20.0}}, "[bench].source_divergence_deg", "must lie in [0, 10]"),
    ({"simulator": {"detector_solid_angle_sr": 1e-3}}, "[simulator].detector_solid_angle_sr",
     "the detector's acceptance is [detector].solid_angle_sr now; remove the old key"),
])
def test_bad_optics_keys_name_file_and_key(over, where, what):
    msg = _err(make_raw(over))
    assert f"bench.toml: {where}: " in msg and what in msg, msg


def test_optics_keys(tmp_path):
    """The optics of the shipped simulated bench; a beam without a sample diameter is refused; the older
    [simulator].detector_solid_angle_sr still sets the cone; a responsivity CSV; gains are a photodiode's."""
    d = config_from_dict(make_raw()).detector
    assert d.acceptance_sr == 1e-3 and d.gains == (1.0, 10.0, 100.0, 1000.0, 10000.0)
    assert abs(d.band_weights.sum() - 1.0) < 1e-12 and d.band_weights[-1] > 10 * d.band_weights[0]  # red-heavy
    raw = make_raw()
    del raw["bench"]["sample_diameter_mm"]
    assert "[bench].sample_diameter_mm: missing: beam_diameter_mm is given" in _err(raw)
    raw = make_raw({"simulator": {"detector_solid_angle_sr": 2e-3}})
    del raw["detector"]["solid_angle_sr"]
    assert config_from_dict(raw).detector.acceptance_sr == 2e-3
    assert config_from_dict(make_raw({"detector": {"type": "spectrometer"}})).detector.gains is None
    (tmp_path / "flat.csv").write_text("wavelength_nm,responsivity\n380,0.5\n780,0.5\n")
    raw = make_raw({"detector": {"responsivity": "flat.csv"}, "bench": {"source_spectrum": "D65"}})
    w = config_from_dict(raw, tmp_path / "bench.toml").detector.band_weights
    assert w.argmax() < w.size // 2  # D65 on a flat detector: more weight in the blue than halogen on silicon
    half = make_raw({"detector": {"aperture_half_angle_deg": 1.0}})
    del half["detector"]["solid_angle_sr"]
    assert abs(config_from_dict(half).detector.acceptance_sr - 2 * 3.141592653589793 * (1 - 0.9998476951563913)) \
        < 1e-12
