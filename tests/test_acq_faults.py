"""Fault runs on the simulator ([simulator.faults] in a temporary copy of the config): dropped replies and corrupt
bytes on both ports, servo overloads, stepper stalls, a vanishing port, saturated readings. The capture either
completes or stops safely; after --resume the slice holds exactly the planned samples, none twice."""

from __future__ import annotations

import json

import numpy as np
import pytest

from acquisition import Bench, HardwareError
from acquisition.cli import main
from tests.helpers import planned
from tests.test_acq_support import integration_times, keys, make_raw, read, write_config, zscores


def assert_exact(out, cfg):
    s = read(out / "slice.csv")  # the reader rejects duplicate samples
    assert sorted(keys(s)) == planned(cfg)
    assert len(set(keys(s))) == len(s)
    return s


def resume_until_done(tmp_path, capsys, raw, out, max_runs=12, reseed=True):
    """Run, then --resume until the capture completes; every stopped run must say how to resume."""
    codes = []
    for run in range(max_runs):
        r = raw if not reseed else make_raw(raw, {"simulator": {"seed": 100 + run}}, fast=False)
        cfg = write_config(tmp_path / f"run{run}.toml", r)
        args = ["--config", str(cfg), "--out", str(out), "--no-progress"] + (["--resume"] if run else [])
        rc = main(args)
        err = capsys.readouterr().err
        codes.append(rc)
        if rc == 0:
            return cfg, codes
        assert rc == 1, err
        assert "--resume" in err and "safely in" in err, err
    raise AssertionError(f"capture not complete after {max_runs} runs: exit codes {codes}")


@pytest.mark.parametrize("motion", ["dynamixel", "serial"])
def test_comm_faults_are_retried(tmp_path, capsys, motion):
    raw = make_raw({"bench": {"motion": motion},
                    "simulator": {"faults": {"drop_reply_rate": 0.03, "corrupt_byte_rate": 0.002,
                                             "serial_comm_faults": True}}})
    cfg = write_config(tmp_path / "comm.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0, capsys.readouterr().err
    s = assert_exact(out, cfg)
    z, _ = zscores(raw, s)
    assert np.all(np.abs(z) < 5.0)  # no corrupt reading slipped through
    log = (out / "capture.log").read_text()
    assert "retrying" in log
    counts = (out / "simulator.log").read_text()
    assert "'dropped': 0, 'corrupted': 0" not in counts.split("serial")[1][:60]  # faults did happen on serial


@pytest.mark.slow
def test_overloads_stop_safely_and_resume_exactly(tmp_path, capsys):
    raw = make_raw({"simulator": {"faults": {"overload_rate": 0.12}}})
    out = tmp_path / "out"
    cfg, codes = resume_until_done(tmp_path, capsys, raw, out)
    assert 1 in codes  # at least one overload stopped a run
    assert_exact(out, cfg)
    log = (out / "capture.log").read_text()
    assert "hardware error: overload" in log and "All servos were switched to torque off" in log
    runs = json.loads((out / "capture.json").read_text())["runs"]
    assert [r["status"] for r in runs][-1] == "complete" and len(runs) == len(codes)
    assert sum(r["samples_new"] for r in runs) == len(planned(cfg))  # none measured twice


@pytest.mark.slow
def test_stepper_stalls_stop_safely_and_resume_exactly(tmp_path, capsys):
    raw = make_raw({"bench": {"motion": "serial"}, "simulator": {"faults": {"stall_rate": 0.1}}})
    out = tmp_path / "out"
    cfg, codes = resume_until_done(tmp_path, capsys, raw, out)
    assert 1 in codes
    assert_exact(out, cfg)
    log = (out / "capture.log").read_text()
    assert "alarm 21 (an axis stalled)" in log and "RESET" in log


@pytest.mark.slow
def test_vanished_port_then_resume(tmp_path, capsys):
    raw = make_raw({"simulator": {"faults": {"port_vanish_after_s": 4.5, "vanish_ports": "dynamixel"}}})
    cfg = write_config(tmp_path / "vanish.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "Dynamixel bus on /dev/pts/" in err and "port failed" in err and "--resume" in err
    n1 = len(read(out / "slice.csv"))
    assert 0 < n1 < len(planned(cfg))
    fixed = write_config(tmp_path / "fixed.toml", make_raw())
    assert main(["--config", str(fixed), "--out", str(out), "--resume", "--no-progress"]) == 0
    s = assert_exact(out, fixed)
    # the calibration stored at the start is reused: the resumed samples agree with the first ones
    z, _ = zscores(make_raw(), s)
    assert np.all(np.abs(z) < 5.0)


def test_serial_port_vanishing_parks_the_servos(tmp_path, capsys):
    raw = make_raw({"simulator": {"faults": {"port_vanish_after_s": 4.5, "vanish_ports": "serial"}}})
    cfg = write_config(tmp_path / "vanish.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    assert "serial controller on /dev/pts/" in capsys.readouterr().err
    log = (out / "capture.log").read_text()
    assert "arms parked at (0, 45)" in log and "motion released (torque off)" in log


def test_saturation_faults_are_reread(tmp_path, capsys):
    raw = make_raw({"simulator": {"faults": {"saturate_rate": 0.03}}})
    cfg = write_config(tmp_path / "sat.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    s = assert_exact(out, cfg)
    z, _ = zscores(raw, s, integration_times(out, s))  # a transient seen twice ranges the point down
    assert np.all(np.abs(z) < 5.0)
    assert "saturated" in (out / "capture.log").read_text()


@pytest.mark.slow
def test_real_saturation_stops_with_advice(tmp_path, capsys):
    """Without auto-ranging a saturating detector stops the capture; with it, when even the shortest allowed
    integration time saturates."""
    raw = make_raw({"simulator": {"source_power": 1.0e9}, "detector": {"auto_range": False}})
    cfg = write_config(tmp_path / "bright.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "white reference: the detector saturates" in err and "integration_time_s" in err
    assert "auto_range = true" in err
    raw = make_raw({"simulator": {"source_power": 1.0e9}, "detector": {"min_integration_time_s": 0.01}})
    cfg = write_config(tmp_path / "bright2.toml", raw)
    assert main(["--config", str(cfg), "--out", str(tmp_path / "out2"), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "white reference: the detector saturates (65535 counts) even at the lowest gain (1) and the shortest " \
           "integration time, " \
           "[detector].min_integration_time_s = 0.01 s" in err


def test_refused_goal_is_a_hardware_error_and_reconnect_reboots(tmp_path, caplog):
    """A goal the servos refuse (arms would collide: the simulator latches an overload) is detected from the alert
    bit; the arms are released; a new connect reboots the servos and motion works again."""
    cfg = write_config(tmp_path / "c.toml", make_raw())
    with Bench.from_config(cfg) as bench:
        bench.move(30.0, 20.0)
        with pytest.raises(HardwareError, match=r"servo \d \((light|detector) arm\): hardware error: overload"):
            bench.motion.move({"light": 30.0, "detector": -30.0})  # bypasses the plan checks on purpose
        assert not bench.motion.healthy()
        bench.motion.hw_errors.clear()
        bench.motion.connect()
        assert "rebooting it" in caplog.text
        bench.move(40.0, 40.0)
        ti, to = bench.positions()
        assert abs(ti - 40.0) < 0.25 and abs(to - 40.0) < 0.25


@pytest.mark.slow
def test_failure_before_the_first_sample_says_nothing_was_captured(tmp_path, capsys):
    raw = make_raw({"simulator": {"faults": {"port_vanish_after_s": 0.1, "vanish_ports": "serial"}}})
    cfg = write_config(tmp_path / "early.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "No sample was captured yet." in err and "safely in" not in err, err
    assert f"Resume with: gonio-capture --config {cfg} --out {out} --resume" in err
    assert not (out / "slice.csv").exists()
    fixed = write_config(tmp_path / "fixed.toml", make_raw())
    assert main(["--config", str(fixed), "--out", str(out), "--resume", "--no-progress"]) == 0
    assert_exact(out, fixed)
