"""The GRBL driver (acquisition.devices.grbl) against the project's own virtual GRBL (simulator.devices.grbl) on a
pseudo-terminal: homing with switches, the settings check, error and alarm sentences, the soft-limit alarm, the
refused resume after an alarm; the bench file's ``[motion] type = "grbl"``; the coordinated-line time model."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from acquisition.config import load_config
from acquisition.devices import grbl_settings
from acquisition.devices.grbl import GrblAxes, GrblError, parse_status
from acquisition.errors import ConfigError, DeviceError, HardwareError
from reconstruction.instrument.timing import AxisTiming, MoveTiming, line_durations, trapezoid_duration
from simulator.bench import VirtualBench
from simulator.config import load_config as sim_load_config
from simulator.ports.transports import PtyServer
from tests import helpers

GRBL_TOML = Path(__file__).resolve().parents[1] / "configs" / "grbl-bench.toml"


def _raw() -> dict:
    import tomllib

    return tomllib.loads(GRBL_TOML.read_text())


def _write(tmp_path: Path, over: dict, name: str = "bench.toml") -> Path:
    p = tmp_path / name
    p.write_text(tomli_w.dumps(helpers.deep_merge(_raw(), over)))
    return p


@pytest.fixture
def rig(tmp_path):
    """``rig(over)`` -> (driver, virtual GRBL) on a pty; closed at the end."""
    made = []

    def make(over: dict | None = None, unlock_port: str | None = None):
        path = _write(tmp_path, over or {}, f"bench{len(made)}.toml")
        bench = VirtualBench(sim_load_config(path))
        server = PtyServer(bench)
        made.append(server)
        cfg = load_config(path)
        drv = GrblAxes(server.paths()["grbl"], cfg.axes, cfg.motion)
        made.append(drv)
        return drv, bench.grbl, server, cfg

    yield make
    for m in made:
        m.close()


def test_codes_cover_grbl_tables_in_one_sentence_each():
    for code, text in {**grbl_settings.ERRORS, **grbl_settings.ALARMS}.items():
        assert text and "\n" not in text and code > 0
    assert grbl_settings.error_text(9).startswith("error:9: G-code is locked out")
    assert grbl_settings.alarm_text(3).startswith("ALARM:3: reset while moving")
    assert "does not document" in grbl_settings.error_text(99)
    # that they cover GRBL's own tables: tests/test_grbl_conformance.py (it needs ../shared/grbl)


def test_status_reports_parse():
    st = parse_status("<Hold:0|MPos:1.500,-2.000,0.000|FS:0,0|Pn:XY>")
    assert (st.state, st.sub, st.mpos) == ("Hold", 0, (1.5, -2.0, 0.0))
    assert parse_status("<Idle|WPos:1,2,3|FS:0,0>") is None and parse_status("ok") is None


def test_connect_homes_onto_the_switches_then_moves(rig):
    drv, grbl, _, cfg = rig()
    assert grbl.state == "Alarm"  # homing enabled: GRBL powers up locked
    drv.connect()
    assert drv.trusted and grbl.state == "Idle"
    pos = drv.positions()  # pulled off the switches ($27 = 1 deg) below the max_deg ends
    assert pos["light"] == pytest.approx(79.0, abs=0.03) and pos["detector"] == pytest.approx(84.0, abs=0.03)
    drv.move({"light": 30.0, "detector": -20.0})
    assert drv.positions() == pytest.approx({"light": 30.0, "detector": -20.0}, abs=cfg.motion.tolerance_deg)
    assert grbl.arm_angles(grbl.clock.now()) == pytest.approx((30.0, -20.0), abs=0.03)


def test_settings_that_differ_are_named_and_nothing_moves(rig):
    drv, grbl, _, _ = rig()
    grbl.settings[100] = 250.0
    grbl.settings[121] = 10.0
    with pytest.raises(DeviceError) as e:
        drv.connect()
    msg = str(e.value)
    assert "$100 (X steps per degree (light arm)) is 250, the bench file needs 44.444 ([axes.light].units_per_deg)" \
        in msg
    assert "$121 (Y acceleration, deg/s^2) is 10, the bench file needs 240.000" in msg
    assert "$101" not in msg and "$110" not in msg
    assert "Nothing was moved" in msg
    assert grbl.state == "Alarm"  # not even homed


def test_soft_limits_travel_too_short_is_named(rig):
    drv, grbl, _, _ = rig()
    grbl.settings[131] = 100.0
    with pytest.raises(DeviceError, match=r"\$131 \(Y maximum travel, deg\) is 100, the bench file needs at least "
                                          r"170.000"):
        drv.connect()


def test_gcode_error_is_one_sentence(rig):
    drv, _, _, _ = rig()
    drv.connect()
    with pytest.raises(GrblError, match=r"'G5 X1' refused: error:20: unsupported or invalid G-code command$"):
        drv.command("G5 X1")


def test_soft_limit_alarm_stops_keeps_the_position_and_parks(rig):
    drv, grbl, _, _ = rig()
    drv.connect()
    drv.move({"light": 20.0, "detector": 10.0})
    with pytest.raises(HardwareError, match=r"ALARM:2: soft limit: .*; the capture stopped$"):
        drv.move({"light": 85.0, "detector": 10.0})  # beyond the switch: machine +5 > 0
    assert drv.trusted and drv.healthy()  # GRBL kept the position: reset + $X, as its documentation allows
    drv.move({"light": 0.0, "detector": 45.0})
    assert drv.positions() == pytest.approx({"light": 0.0, "detector": 45.0}, abs=0.05)


def test_after_a_reset_in_motion_a_resume_refuses_until_unlocked(rig):
    over = {"motion": {"grbl": {"homing": False, "soft_limits": False}}}
    drv, grbl, server, cfg = rig(over)
    drv.connect()
    drv._send({"light": 40.0, "detector": 40.0})
    drv._write(b"\x18")  # the reset button while moving
    drv._await_welcome(2.0)
    assert drv.alarm == 3 and not drv.trusted and not drv.healthy()
    with pytest.raises(DeviceError, match="not trusted since ALARM:3"):
        drv.move({"light": 10.0, "detector": 10.0})
    drv.close()
    again = GrblAxes(server.paths()["grbl"], cfg.axes, cfg.motion)
    with pytest.raises(DeviceError, match=r"not trusted, so nothing moves: home them .* unlock on purpose "
                                          r"\(gonio-capture --unlock, or \[motion.grbl\].unlock = true; \$X\)"):
        again.connect()
    again.close()
    cfg2 = load_config(_write(Path(cfg.path).parent, helpers.deep_merge(over, {"motion": {"grbl": {"unlock": True}}}),
                              "unlock.toml"))
    unlocked = GrblAxes(server.paths()["grbl"], cfg2.axes, cfg2.motion)
    try:
        unlocked.connect()
        assert unlocked.trusted and grbl.state == "Idle"
        unlocked.move({"light": 10.0, "detector": 10.0})
    finally:
        unlocked.close()


def test_stop_holds_then_resets_without_alarm(rig):
    over = {"simulator": {"time_scale": 1.0}, "motion": {"grbl": {"homing": False, "soft_limits": False}}}
    drv, grbl, _, _ = rig(over)
    drv.connect()
    drv._send({"light": 0.0, "detector": -80.0})
    drv.stop()
    assert drv.alarm == 0 and drv.trusted and grbl.state == "Idle"
    assert drv.positions()["detector"] > -80.0 + 1.0  # stopped on the way


@pytest.mark.parametrize("over, key", [
    ({"motion": {"grbl": {"soft_limits": True, "homing": False}}}, r"\[motion.grbl\].soft_limits: GRBL enables"),
    ({"axes": {"light": {"id": "Y"}, "detector": {"id": "X"}}}, r"\[axes.light\].id: the light arm is GRBL's X"),
    ({"bench": {"transport": "serial", "serial_port": "/dev/ttyACM0"}}, r"\[motion.grbl\].port: missing"),
    ({"bench": {"motion": "serial"}}, r"\[motion\].type: is 'grbl' but \[bench\].motion is 'serial'"),
    ({"bench": {"transport": "serial"}, "motion": {"grbl": {"port": "/dev/ttyUSB0"}}},
     r"\[bench\].serial_port: missing"),
    ({"bench": {"transport": "dynamixel", "dynamixel_port": "/dev/ttyUSB1", "serial_port": "/dev/ttyACM1"}},
     r"\[bench\].transport: is \"dynamixel\", but the arms are on GRBL"),
    ({"motion": {"velocity_deg_s": 1000.0}}, r"\[motion\].velocity_deg_s: 1000 deg/s x 44.4444 steps/deg"),
    ({"motion": {"grbl": {"baudrate": "fast"}}}, r"\[motion.grbl\].baudrate"),
    ({"motion": {"grbl": {"homeing": True}}}, r"\[motion.grbl\].homeing: unknown key; did you mean 'homing'"),
])
def test_bench_file_errors_name_the_key(tmp_path, over, key):
    with pytest.raises(ConfigError, match=key):
        load_config(_write(tmp_path, over))


def test_grbl_table_on_another_bench_is_an_error(tmp_path):
    raw = helpers.deep_merge(_raw(), {"bench": {"motion": "serial"}})
    del raw["motion"]["type"]
    p = tmp_path / "b.toml"
    p.write_text(tomli_w.dumps(raw))
    with pytest.raises(ConfigError, match=r"\[motion\].grbl: is for a GRBL bench"):
        load_config(p)


def test_the_time_model_moves_both_arms_on_one_line():
    v, a = (600.0, 600.0), (2400.0, 2400.0)  # steps/s, steps/s^2
    # one arm still: the other's own trapezoid
    assert line_durations(0.0, 300.0, v, a) == pytest.approx(trapezoid_duration(300.0, v[1], a[1]))
    # equal moves: the same trapezoid too (each axis at its own limit)
    assert line_durations(300.0, -300.0, v, a) == pytest.approx(trapezoid_duration(300.0, v[0], a[0]))
    # a short move with a long one: the line is as slow as the long axis' trapezoid
    assert line_durations(30.0, 300.0, v, a) == pytest.approx(trapezoid_duration(300.0, v[1], a[1]))
    # different limits: the line is set by the axis that needs longest at its own limits, or longer
    t = line_durations(200.0, 200.0, (600.0, 300.0), (2400.0, 4800.0))
    assert t >= max(trapezoid_duration(200.0, 600.0, 2400.0), trapezoid_duration(200.0, 300.0, 4800.0)) - 1e-12
    ax = AxisTiming(10.0, 0.0, 1, 600.0, 2400.0)
    mt = MoveTiming(ax, ax, coordinated=True)
    assert mt.move_time((0.0, 0.0), (0.0, 0.0)) == 0.0
    assert mt.move_time((0.0, 0.0), (3.0, 30.0)) == pytest.approx(float(trapezoid_duration(300.0, 600.0, 2400.0)))
    assert np.all(np.isfinite(mt.move_times(np.zeros((3, 2)), np.array([[0, 0], [1, 0], [0, 1.0]]))))
    assert not math.isnan(mt.move_time((1.0, 2.0), (1.0, 2.0)))


@pytest.mark.slow
def test_ctrl_c_holds_resets_parks_and_the_capture_resumes(tmp_path):
    import signal

    from tests.test_acq_signals import rows, wait_for_rows
    from tests.test_acq_support import popen_capture, run_capture

    no_switches = {"motion": {"grbl": {"homing": False, "soft_limits": False}}}
    slow = _write(tmp_path, {**no_switches, "simulator": {"time_scale": 8.0}}, "slow.toml")
    out = tmp_path / "out"
    p = popen_capture("--config", str(slow), "--out", str(out), "--no-progress")
    wait_for_rows(out / "slice.csv", 4, p)
    p.send_signal(signal.SIGINT)
    _, err = p.communicate(timeout=60)
    assert p.returncode == 130, err
    log = (out / "capture.log").read_text()
    assert "arms parked at (0, 45)" in log, log  # the hold completed before the reset: no ALARM:3, the position kept
    assert "ALARM" not in log
    n1 = rows(out / "slice.csv")
    fast = _write(tmp_path, no_switches, "fast.toml")
    r = run_capture("--config", str(fast), "--out", str(out), "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert rows(out / "slice.csv") > n1


def test_unlock_flag_is_for_grbl_benches_only(tmp_path):
    from tests.test_acq_support import run_capture

    serial_bench = Path(__file__).resolve().parents[1] / "configs" / "serial-bench.toml"
    r = run_capture("--config", str(serial_bench), "--check", "--unlock")
    assert r.returncode != 0
    assert "--unlock is for a GRBL bench ([motion] type = \"grbl\"); this bench's motion is 'serial'" in r.stderr
    r = run_capture("--config", str(GRBL_TOML), "--check", "--unlock")
    assert r.returncode == 0, r.stderr


def test_stock_grbl_homes_z_first_ends_in_alarm_9_and_the_driver_says_to_flash_ours(rig):
    drv, grbl, _, _ = rig({"simulator": {"grbl_build": "stock"}})  # the release hex: HOMING_CYCLE_0 is Z
    with pytest.raises(DeviceError) as e:
        drv.connect()
    msg = str(e.value)
    assert "ALARM:9: homing failed: no limit switch within the search distance" in msg
    assert "looks like the stock build" in msg and "make -C firmware/grbl" in msg and "\n" not in msg
    assert grbl.state == "Alarm" and not drv.trusted
    assert grbl.arm_angles(grbl.clock.now()) == pytest.approx((0.0, 45.0))  # Z searched, the arms never moved


def test_our_build_homes_one_arm_on_its_own_the_stock_one_refuses(rig):
    drv, grbl, _, cfg = rig()
    drv.connect()
    drv.move({"light": 30.0, "detector": -20.0})
    assert drv.command("$HX") == []  # the light arm only: back at its pull-off, the detector where it was
    assert drv.positions() == pytest.approx({"light": 79.0, "detector": -20.0}, abs=cfg.motion.tolerance_deg)
    stock, _, _, _ = rig({"simulator": {"grbl_build": "stock"}, "motion": {"grbl": {"homing": False,
                                                                                     "soft_limits": False}}})
    with pytest.raises(GrblError, match="error:3"):
        stock.command("$HX")


def test_status_is_polled_at_most_5_hz_while_the_move_is_expected_to_run(rig):
    over = {"simulator": {"time_scale": 1.0}, "motion": {"grbl": {"homing": False, "soft_limits": False}}}
    drv, grbl, _, _ = rig(over)
    drv.connect()
    asked: list[float] = []  # the virtual GRBL's clock at each '?' it received
    process = grbl.process

    def counting(data: bytes) -> bytes:
        asked.extend([grbl.clock.now()] * data.count(b"?"))
        return process(data)

    grbl.process = counting
    goal = {"light": 80.0, "detector": -80.0}
    expected = drv._expected_s(goal)
    # from machine 0 (no switches: light 80, detector 85 deg): the detector turns 165 deg, the longer axis
    assert expected == pytest.approx(trapezoid_duration(165.0, 60.0, 240.0), rel=1e-6)
    t0 = grbl.clock.now()
    drv.move(goal)
    running = [t for t in asked if t < t0 + expected]
    assert len(running) <= expected / 0.2 + 1, (len(running), expected)  # GRBL's interface.md: <= 5 Hz
    assert drv.positions() == pytest.approx(goal, abs=0.05)


def test_after_a_reset_in_motion_the_advice_is_the_resume_that_works(rig):
    over = {"motion": {"grbl": {"homing": False, "soft_limits": False}}}
    drv, grbl, _, _ = rig(over)
    drv.connect()
    assert drv.resume_flags == ""
    drv._send({"light": 40.0, "detector": 40.0})
    drv._write(b"\x18")  # the reset button while moving: ALARM:3, no switches to home with
    drv._await_welcome(2.0)
    assert drv.resume_flags == " --unlock"
    with pytest.raises(HardwareError, match=r"ALARM:3: .*; the capture stopped; check the arms are where GRBL "
                                            r"believes them \(or move them there\), then resume with --resume "
                                            r"--unlock \(\$X on purpose\)$"):
        drv._alarm_stop(3)
    homing, _, _, _ = rig()
    homing.connect()
    homing.trusted = False
    assert homing.resume_flags == ""  # a bench with switches: the resume homes ($H)
