"""The GRBL driver against GRBL 1.1h's own code: grbl-sim built from ``../shared/grbl`` with the project's
configuration (``firmware/grbl``: the two arms' homing cycle) and shim (the limit switches driven by the simulated
arms; GRBL's main loop and interrupts on one thread) into a temporary folder (once per session), run on a
pseudo-terminal (tests/grbl_harness.py) and driven by ``acquisition.devices.grbl``.

Moves land and read back; settings that differ are named before anything moves; feed hold and soft reset behave
as GRBL documents (``Hold:1`` -> ``Hold:0`` with the position frozen, ``~`` resumes; 0x18 in motion -> ``ALARM:3``,
the position no longer trusted, a new connection refused until unlocked on purpose); a whole capture runs with the
arms on grbl-sim (the detector's angles from its step output) and the detector on gonio-sim; a reset mid-sweep
stops the capture with one sentence and a resumable folder. Homing and limits (``conformance`` and ``homing`` or
``limit`` in the names): ``$H`` homes both arms at once and reports the pull-off; the stock configuration ends in
ALARM:9 (no Z switch) and the driver says to flash ours; a switch that never closes is ALARM:9, named; a switch hit
mid-move with ``$21=1`` is ALARM:1, the capture stops where GRBL stopped it, and a resume homes and completes it;
soft limits refuse a move beyond travel in one sentence. grbl-sim is CPU-bound near real time: the settings are
raised ($110/$111, $120/$121) and the plans short. Without the GRBL sources or gcc/make the module skips, saying
what is missing and how to get it (test_grbl_conformance_passes_beside_two_cpu_burners runs this module's motion
tests beside two CPU burners, tests/grbl_under_load.py).
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgspec
import pytest
import tomli_w

from tests import grbl_harness as gh

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 only
    import tomli as tomllib

pytestmark = pytest.mark.slow

_MISSING = gh.missing()
if _MISSING is not None:
    pytest.skip(f"GRBL conformance tests skipped: {_MISSING}.", allow_module_level=True)

from acquisition.devices.grbl import GrblAxes  # noqa: E402
from acquisition.errors import DeviceError, HardwareError  # noqa: E402
from reconstruction.schema.bench import Axis, GrblTable, MotionTable  # noqa: E402

UPD = 10.0  # steps per degree: few steps, so grbl-sim (CPU-bound) keeps near real time
# the bench without switches (our build's defaults home and limit: off here, and unlocked)
FAST = {100: UPD, 101: UPD, 110: 36000.0, 111: 36000.0, 120: 4000.0, 121: 4000.0, 20: 0, 21: 0, 22: 0}
# with switches at the max_deg ends: fast homing (seek 100 deg/s, locate 10 deg/s, 10 ms debounce, 1 deg pull-off)
HOMING = {**FAST, 20: 1, 21: 0, 22: 1, 23: 0, 24: 600.0, 25: 6000.0, 26: 10, 27: 1.0, 130: 80.0, 131: 170.0}
SWITCHES = "x=-150,y=-200"  # the arms start 15 and 20 deg below their switches
POLL_S = 0.05
AXES = {"light": Axis(name="light", id="X", units_per_deg=UPD, zero_offset=0.0, direction=1, min_deg=0.0,
                      max_deg=80.0, park_deg=0.0),
        "detector": Axis(name="detector", id="Y", units_per_deg=UPD, zero_offset=0.0, direction=1, min_deg=-85.0,
                         max_deg=85.0, park_deg=0.0)}
# machine 0 (the switch) at max_deg, as docs/build-a-bench.md sets zero_offset
HOMED_AXES = {n: msgspec.structs.replace(a, zero_offset=-UPD * a.max_deg) for n, a in AXES.items()}


# slow moves (20 deg/s, 100 deg/s^2) for the tests that act while an arm moves: seconds of simulated time, so a
# test process held back by a busy machine still acts in motion (grbl-sim runs on, whatever the test does)
SLOW = {**FAST, 110: 1200.0, 111: 1200.0, 120: 100.0, 121: 100.0}


def motion(acc: float = FAST[120], vel: float = FAST[110] / 60, **grbl) -> MotionTable:
    # retries 30: a status report may wait on grbl-sim (CPU-bound) for seconds on a loaded machine
    return MotionTable(profile_velocity=0, profile_acceleration=0, velocity_deg_s=vel, acceleration_deg_s2=acc,
                       tolerance_deg=0.05, settle_s=0.0, timeout_s=60.0, retries=30, poll_interval_s=POLL_S,
                       type="grbl", grbl=GrblTable(boot_s=0.3, **grbl))


def slow_motion(**grbl) -> MotionTable:
    return motion(SLOW[120], SLOW[110] / 60, **grbl)


@pytest.fixture(scope="session")
def grbl_exe(tmp_path_factory) -> Path:
    return gh.build(tmp_path_factory.mktemp("grbl-sim-build"))


@pytest.fixture(scope="session")
def stock_exe(tmp_path_factory) -> Path:
    return gh.build(tmp_path_factory.mktemp("grbl-sim-stock"), "stock")


@pytest.fixture
def start_sim(grbl_exe, tmp_path):
    """``start_sim(switches="", slip="", exe=None)`` -> a ready grbl-sim (our build unless ``exe``)."""
    made: list[gh.GrblSim] = []

    def start(switches: str = "", slip: str = "", exe: Path | None = None) -> gh.GrblSim:
        g = gh.GrblSim(exe or grbl_exe, tmp_path / f"grbl{len(made)}", switches=switches, slip=slip)
        made.append(g)
        g.wait_ready()
        return g

    yield start
    for g in made:
        g.close()
        assert g.stall is None, g.stall  # the shim's one-thread clock: no frozen move, ever


@pytest.fixture
def sim(start_sim):
    return start_sim()


def configure(g: gh.GrblSim, settings: dict[int, float] = FAST) -> None:
    for n, v in sorted(settings.items(), key=lambda kv: kv[0] != 22):  # homing before soft limits (error:10)
        assert g.send_line(f"${n}={v:g}")[-1] == "ok"
    if not settings.get(22):
        g.send_line("$X")  # our build powers up locked (homing on by default); this bench has no switches
    g.release()


def test_moves_land_and_positions_read_back(sim):
    configure(sim)
    from simulator.world.stepfile import GrblSimTrack

    drv = GrblAxes(sim.port, AXES, motion())
    try:
        drv.connect()
        assert drv.version.startswith("[VER:1.1h")
        track = GrblSimTrack(sim.steps_path, sim.blocks_path, AXES["light"], AXES["detector"])
        for goal in ((30.0, -40.0), (10.5, 52.3), (0.0, 0.0)):
            drv.move({"light": goal[0], "detector": goal[1]})
            pos = drv.positions()
            assert pos["light"] == pytest.approx(goal[0], abs=0.051)
            assert pos["detector"] == pytest.approx(goal[1], abs=0.051)
            # the step output (what the detector's physics is fed) agrees with GRBL's MPos, step for step (once
            # the relay has copied grbl-sim's lines: a loaded machine may hold its thread back a moment)
            want = (pos["light"], pos["detector"])
            deadline = time.monotonic() + 30.0
            while track(0.0) != pytest.approx(want, abs=1e-9) and time.monotonic() < deadline:
                time.sleep(0.01)
            assert track(0.0) == pytest.approx(want, abs=1e-9), (track.starts, track.targets, track.last)
    finally:
        drv.close()


def test_settings_that_differ_are_named_before_anything_moves(sim):
    sim.release()  # our build's defaults (firmware/grbl/gonio_config.h): the bench's, homing and soft limits on
    drv = GrblAxes(sim.port, AXES, motion())
    try:
        with pytest.raises(DeviceError) as e:
            drv.connect()
        msg = str(e.value)
        for n in (100, 101, 110, 111, 120, 121, 20, 22):
            assert f"${n} " in msg
        assert "$100 (X steps per degree (light arm)) is 44.444, the bench file needs 10.000" in msg
        assert "$20 (soft limits enable) is 1, the bench file needs 0" in msg
        assert "Nothing was moved" in msg and "\n" not in msg
        assert drv.status().mpos[:2] == (0.0, 0.0)
    finally:
        drv.close()


def _a_slow_move_running(drv: GrblAxes) -> float:
    """Connect ``drv`` and start a move slow enough to be caught in motion; return once GRBL reports Run (with
    the deadline that wait had, time.monotonic() s)."""
    drv.connect()
    drv._send({"light": 40.0, "detector": 40.0})
    deadline = time.monotonic() + 60
    while drv.status().state != "Run":
        assert time.monotonic() < deadline, "never saw the move run"
        time.sleep(POLL_S)
    return deadline


def test_feed_hold_resume_and_reset_as_grbl_documents(sim):
    configure(sim, SLOW)  # slow enough to catch in motion
    drv = GrblAxes(sim.port, AXES, slow_motion())
    try:
        deadline = _a_slow_move_running(drv)
        drv._holding = True  # this test's own hold (the driver's stop() sets it too)
        drv._write(b"!")
        states = []
        while True:
            st = drv.status()
            states.append(st.state + ("" if st.sub is None else f":{st.sub}"))
            if states[-1] == "Hold:0":
                break
            assert time.monotonic() < deadline + 60, states
            time.sleep(POLL_S)
        held = drv.status().mpos
        time.sleep(0.3)
        assert drv.status().mpos == held  # stopped in the hold
        assert 0 < held[0] < 40
        drv._write(b"~")  # cycle start: the move goes on to its goal
        drv._wait({"light": 40.0, "detector": 40.0}, check_cancel=False)
        drv._holding = False
        # a soft reset in motion: ALARM:3, the position no longer trusted
        drv._send({"light": 0.0, "detector": -80.0})  # 120 deg, 6 s: still running when the reset arrives
        while drv.status().state != "Run":
            assert time.monotonic() < deadline + 90, "never saw the move run"
        drv._write(b"\x18")
        drv._await_welcome(3.0)
        assert drv.alarm == 3 and not drv.trusted
        assert drv.status().state == "Alarm"
        with pytest.raises(DeviceError, match="not trusted since ALARM:3: reset while moving"):
            drv.move({"light": 10.0, "detector": 10.0})
    finally:
        drv.close()
    again = GrblAxes(sim.port, AXES, slow_motion())
    try:  # a resume refuses ...
        with pytest.raises(DeviceError, match="not trusted, so nothing moves"):
            again.connect()
    finally:
        again.close()
    unlocked = GrblAxes(sim.port, AXES, slow_motion(unlock=True))
    try:  # ... until the user unlocks on purpose
        unlocked.connect()
        unlocked.move({"light": 20.0, "detector": 20.0})
        assert unlocked.positions()["light"] == pytest.approx(20.0, abs=0.051)
    finally:
        unlocked.close()


def test_stop_is_hold_then_reset_and_keeps_the_position(sim):
    configure(sim, SLOW)  # slow enough to catch in motion
    drv = GrblAxes(sim.port, AXES, slow_motion())
    try:
        _a_slow_move_running(drv)
        drv.stop()
        assert drv.alarm == 0 and drv.trusted  # the hold completed before the reset: no ALARM:3
        st = drv.status()
        assert st.state == "Idle" and 0 < st.mpos[0] < 40
        drv.move({"light": 5.0, "detector": 5.0})  # and it moves on from there
    finally:
        drv.close()


def _bench_file(path: Path, detector_port: str, grbl_port: str, base: dict, axes: dict = AXES, **grbl) -> Path:
    raw = {k: v for k, v in base.items() if k not in ("simulator",)}
    raw["bench"] = {**{k: v for k, v in base["bench"].items() if k not in ("motion", "simulator_command")},
                    "transport": "serial", "serial_port": detector_port}
    raw["axes"] = {n: {"id": a.id, "units_per_deg": UPD, "zero_offset": a.zero_offset, "direction": 1,
                       "min_deg": a.min_deg,
                       "max_deg": a.max_deg, "park_deg": 10.0 if n == "light" else 30.0} for n, a in axes.items()}
    raw["motion"] = {"type": "grbl", "velocity_deg_s": FAST[110] / 60, "acceleration_deg_s2": FAST[120],
                     "tolerance_deg": 0.05, "settle_s": 0.0, "timeout_s": 60.0, "retries": 30,
                     "poll_interval_s": POLL_S,
                     "grbl": {"port": grbl_port, "boot_s": 0.3, **grbl}}
    raw["plan"] = {"theta_i_deg": [30.0], "theta_o_min_deg": -10.0, "theta_o_max_deg": 70.0, "theta_o_step_deg": 20.0,
                   "repeats": 2, "dark_at_end": False}
    raw["calibration"] = {**base["calibration"], "reference_theta_i_deg": 10.0, "reference_theta_o_deg": 30.0}
    raw["simulator"] = {**base.get("simulator", {}), "time_scale": 0.0}
    path.write_text(tomli_w.dumps(raw))
    return path


@pytest.fixture
def detector_for(tmp_path, base_config_dict, serve_process):
    """``detector_for(grbl_sim, axes)``: gonio-sim serving the detector only, its arms' angles from that
    grbl-sim's step output."""
    procs = []

    def make(g: gh.GrblSim, axes: dict = AXES):
        sim_cfg = tmp_path / f"detector-sim{len(procs)}.toml"
        raw = dict(base_config_dict)
        raw["bench"] = {**raw["bench"], "motion": "grbl"}
        raw["axes"] = {n: {"id": a.id, "units_per_deg": UPD, "zero_offset": a.zero_offset, "direction": 1,
                           "min_deg": a.min_deg, "max_deg": a.max_deg, "park_deg": 0.0} for n, a in axes.items()}
        sim_cfg.write_text(tomli_w.dumps(raw))
        sp = serve_process(sim_cfg, "--arm-steps", str(g.steps_path), "--arm-blocks", str(g.blocks_path))
        procs.append(sp)
        return sp

    yield make
    for sp in procs:
        sp.stop()


@pytest.fixture
def detector_sim(sim, detector_for):
    return detector_for(sim)


def test_a_capture_runs_with_the_arms_on_grbl(sim, detector_sim, tmp_path, base_config_dict):
    from acquisition import Bench

    configure(sim)
    cfg = _bench_file(tmp_path / "bench.toml", detector_sim.ports["serial"], sim.port, base_config_dict)
    res = Bench.from_config(cfg).capture(out=tmp_path / "cap", progress=False, handle_signals=False)
    assert res.ok, res
    rows = (tmp_path / "cap" / "slice.csv").read_text().splitlines()
    data = [r.split(",") for r in rows if r and not r.startswith("#")][1:]
    assert len(data) == 5
    # the specular direction (theta_o = 30) is the brightest: the detector saw the angles grbl-sim's arms reached
    vals = {float(r[1]): float(r[2]) for r in data}
    assert max(vals, key=vals.get) == 30.0
    # and the same capture on the project's virtual GRBL (same seed, so the same noise) reads the same slice
    virt = _bench_file(tmp_path / "virtual.toml", "", "", base_config_dict)
    raw = tomllib.loads(virt.read_text())
    raw["bench"].update(transport="simulated", motion="grbl", serial_port="")
    raw["motion"]["grbl"].pop("port")
    raw["simulator"].update(stepper_velocity_deg_s=FAST[110] / 60, stepper_acceleration_deg_s2=FAST[120])
    virt.write_text(tomli_w.dumps(raw))
    res2 = Bench.from_config(virt).capture(out=tmp_path / "virtual", progress=False, handle_signals=False)
    assert res2.ok, res2
    rows2 = (tmp_path / "virtual" / "slice.csv").read_text().splitlines()
    vals2 = {float(r.split(",")[1]): float(r.split(",")[2]) for r in rows2 if r and not r.startswith("#")
             and not r.startswith("theta")}
    assert vals2.keys() == vals.keys()
    for k in vals:
        assert vals[k] == pytest.approx(vals2[k], rel=1e-6), k


def test_a_reset_mid_sweep_stops_the_capture_and_resumes_after_unlock(sim, detector_sim, tmp_path,
                                                                      base_config_dict):
    from acquisition import Bench

    configure(sim)
    cfg = _bench_file(tmp_path / "bench.toml", detector_sim.ports["serial"], sim.port, base_config_dict)
    out = tmp_path / "cap"

    def reset_at_third_move():  # the reset button pressed while the arms move to the third point
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            if sim.blocks_path.exists() and len(sim.blocks_path.read_text().splitlines()) >= 4:
                sim.inject(b"\x18")
                return
            time.sleep(0.002)

    t = threading.Thread(target=reset_at_third_move, daemon=True)
    t.start()
    res = Bench.from_config(cfg).capture(out=out, progress=False, handle_signals=False)
    t.join(5)
    assert sim.injected == [b"\x18"]
    assert not res.ok
    log = (out / "capture.log").read_text()
    assert "ALARM:3: reset while moving" in log
    # one sentence, and nothing moved after the alarm (parking with the position lost would drive blind): GRBL
    # planned no block after the reset and is still in its alarm state
    assert sum("ALARM:3" in ln and "ERROR" in ln for ln in log.splitlines()) == 1
    # the advice is the resume that works on a bench without switches, not a plain --resume (refused below)
    assert f"Resume with: gonio-capture --config {cfg} --out {out} --resume --unlock" in log
    assert len(sim.blocks_path.read_text().splitlines()) == 4
    probe = GrblAxes(sim.port, AXES, motion())
    try:
        assert probe.status().state == "Alarm"
    finally:
        probe.close()
    done = [r for r in (out / "slice.csv").read_text().splitlines() if r and not r.startswith("#")][1:]
    assert 1 <= len(done) < 5
    # a resume refuses until unlocked on purpose ...
    refused = Bench.from_config(cfg).capture(out=out, resume=True, progress=False, handle_signals=False)
    assert not refused.ok
    assert "the arms' position is not trusted, so nothing moves" in (out / "capture.log").read_text()
    assert len(sim.blocks_path.read_text().splitlines()) == 4
    from tests.test_acq_support import run_capture

    r = run_capture("--config", str(cfg), "--out", str(out), "--resume", "--unlock", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert "unlocking ($X) on purpose" in (out / "capture.log").read_text()
    rows = [r for r in (out / "slice.csv").read_text().splitlines() if r and not r.startswith("#")][1:]
    assert len(rows) == 5


def test_the_relay_calls_a_frozen_run_a_stall_and_a_moving_or_held_one_not():
    """The relay's watcher (every test asserts it saw no stall), on status reports alone (no grbl-sim): Run at one
    MPos for STALL_S is a stall; Run with MPos changing, or Hold:0 (a completed feed hold) at one MPos, is not."""
    clock = [100.0]
    relay = gh.StallWatch()

    def report(text: str, dt: float) -> None:
        clock[0] += dt
        relay.feed(text.encode(), now=clock[0])

    for k in range(40):  # moving: a new MPos every 0.2 s
        report(f"<Run|MPos:{k:.3f},0.000,0.000|FS:600,0>\r\n", 0.2)
    for _ in range(40):  # a completed hold, 8 s at one position
        report("<Hold:0|MPos:39.000,0.000,0.000|FS:0,0>\r\nok\r\n", 0.2)
    assert relay.stall is None
    report("<Run|MPos:39.0", 0.2)  # a report split across reads ...
    report("00,0.000,0.000|FS:600,0>\r\n", 0.0)
    for _ in range(int(gh.STALL_S / 0.2) + 1):  # ... then frozen in Run
        report("<Run|MPos:39.000,0.000,0.000|FS:600,0>\r\n", 0.2)
    assert relay.stall is not None and "Run at MPos 39.000,0.000,0.000" in relay.stall


# -- homing and limits, on GRBL's own code with the project's configuration ------------------------------------------
def _homed_driver(g: gh.GrblSim, settings: dict = HOMING, **grbl) -> GrblAxes:
    configure(g, settings)
    return GrblAxes(g.port, HOMED_AXES, motion(homing=True, soft_limits=bool(settings.get(20)), **grbl))


def test_conformance_homing_homes_both_arms_and_reports_the_pull_off(start_sim):
    g = start_sim(SWITCHES)
    drv = _homed_driver(g)
    try:
        drv.connect()  # $H: one cycle, both arms (firmware/grbl/gonio_config.h)
        assert "H" in drv.options and not drv.stock_build
        st = drv.status()
        assert st.state == "Idle" and st.mpos == (-1.0, -1.0, 0.0), st.raw  # pulled off by $27; Z never moved
        assert "Pn:" not in st.raw  # off both switches
        assert drv.positions() == pytest.approx({"light": 79.0, "detector": 84.0}, abs=1e-9)
        # machine 0 is where each switch closes: 0.5 deg short of it is free, and the arms move as commanded
        drv.move({"light": 79.5, "detector": -40.0})
        assert drv.positions() == pytest.approx({"light": 79.5, "detector": -40.0}, abs=0.051)
    finally:
        drv.close()


def test_conformance_homing_with_stock_grbl_ends_in_alarm_9_and_says_to_flash_ours(start_sim, stock_exe):
    g = start_sim(SWITCHES, exe=stock_exe)  # switches on X and Y, none on Z: the bench as wired
    drv = _homed_driver(g, {**HOMING, 132: 5.0})  # (a short Z search: GRBL homes Z first, for 1.5 x $132)
    try:
        with pytest.raises(DeviceError) as e:
            drv.connect()
        msg = str(e.value)
        assert "ALARM:9: homing failed: no limit switch within the search distance" in msg
        assert "looks like the stock build" in msg and "make -C firmware/grbl" in msg and "\n" not in msg
        assert drv.stock_build and not drv.trusted
        assert drv.status().state == "Alarm" and drv.status().mpos[:2] == (0.0, 0.0)  # the arms never moved
    finally:
        drv.close()


def test_conformance_homing_alarm_9_names_a_switch_that_never_closes(start_sim):
    g = start_sim("x=-150")  # the detector arm's switch is broken (or unplugged): it never closes
    drv = _homed_driver(g)  # searched for 1.5 x $131 = 255 deg
    try:
        with pytest.raises(DeviceError) as e:
            drv.connect()
        msg = str(e.value)
        assert "ALARM:9: homing failed: no limit switch within the search distance" in msg
        assert "check each arm's switch" in msg and "stock" not in msg
        assert "home them" not in msg  # not the advice that just failed
        assert "Pn:X" in drv.status().raw  # the light arm found its switch and sits on it
    finally:
        drv.close()


def test_conformance_soft_limit_refuses_a_move_beyond_travel_in_one_sentence(start_sim):
    g = start_sim(SWITCHES)
    drv = _homed_driver(g)
    try:
        drv.connect()
        drv.move({"light": 40.0, "detector": 10.0})
        beyond = HOMED_AXES["light"].max_deg + 5.0  # machine +5: outside [-$130, 0]
        with pytest.raises(HardwareError) as e:
            drv.move({"light": beyond, "detector": 10.0})
        msg = str(e.value)
        assert "ALARM:2: soft limit: a move target lies outside the machine travel" in msg and "\n" not in msg
        assert msg.endswith("the capture stopped")  # the position was kept: nothing to advise
        assert drv.trusted and drv.status().state == "Idle"  # reset and $X, as GRBL's documentation allows
        assert drv.positions() == pytest.approx({"light": 40.0, "detector": 10.0}, abs=0.051)  # never moved
        drv.move({"light": 20.0, "detector": 30.0})
    finally:
        drv.close()


def test_conformance_hard_limit_mid_move_is_alarm_1_and_the_capture_resumes_after_homing(
        start_sim, detector_for, tmp_path, base_config_dict):
    from acquisition import Bench

    # the detector arm's belt jumps 25 deg towards its switch during the capture (after its 500th step): GRBL's
    # count no longer matches the arm, which reaches its switch on the way to theta_o = 70 deg
    g = start_sim(SWITCHES, slip="y:+250@500")
    configure(g, {**HOMING, 21: 1})
    det = detector_for(g, HOMED_AXES)
    cfg = _bench_file(tmp_path / "bench.toml", det.ports["serial"], g.port, base_config_dict, HOMED_AXES,
                      homing=True, soft_limits=True)
    out = tmp_path / "cap"
    res = Bench.from_config(cfg).capture(out=out, progress=False, handle_signals=False)
    assert not res.ok
    log = (out / "capture.log").read_text()
    errors = [ln for ln in log.splitlines() if "ERROR" in ln and "ALARM:1" in ln]
    assert len(errors) == 1, log
    assert "ALARM:1: hard limit switch triggered" in errors[0]
    assert "resume with --resume: the arms are homed ($H) first" in errors[0]
    assert "--unlock" not in log  # the bench homes: unlocking is not the advice
    assert "arms parked" not in log  # not parked blind: the arm stays where GRBL stopped it
    done = [r for r in (out / "slice.csv").read_text().splitlines() if r and not r.startswith("#")][1:]
    assert 1 <= len(done) < 5
    again = Bench.from_config(cfg).capture(out=out, resume=True, progress=False, handle_signals=False)
    assert again.ok, again
    assert "homing ($H)" in (out / "capture.log").read_text()
    rows = [r for r in (out / "slice.csv").read_text().splitlines() if r and not r.startswith("#")][1:]
    assert len(rows) == 5


def test_conformance_a_feed_hold_from_outside_is_named_at_once(sim):
    configure(sim, SLOW)  # slow enough to catch in motion
    drv = GrblAxes(sim.port, AXES, slow_motion())

    def hold_button():  # another program sends '!' once the move runs
        deadline = time.monotonic() + 180
        while time.monotonic() < deadline:
            if sim.blocks_path.exists() and len(sim.blocks_path.read_text().splitlines()) >= 1:
                time.sleep(0.1)
                sim.inject(b"!")
                return
            time.sleep(0.002)

    try:
        drv.connect()
        t = threading.Thread(target=hold_button, daemon=True)
        t.start()
        with pytest.raises(HardwareError) as e:  # named, not "still move after 20 s"
            drv.move({"light": 60.0, "detector": 60.0})
        t.join(5)
        assert sim.injected == [b"!"]
        msg = str(e.value)
        assert "a feed hold came from outside gonio-capture" in msg and "the position is kept" in msg
        assert drv.trusted and drv.status().state == "Idle"  # hold completed, then reset: no ALARM:3
        assert 0 < drv.positions()["light"] < 60
    finally:
        drv.close()


@pytest.mark.skipif(shutil.which("avr-gcc") is None, reason="avr-gcc is not installed (scripts/system-packages.sh)")
def test_conformance_homing_the_hex_a_lab_flashes_leaves_z_out(tmp_path):
    """``make -C firmware/grbl`` builds the Uno's hex from the same configuration the tests above ran."""
    r = subprocess.run(["make", "-s", "-C", str(gh.FIRMWARE), f"GRBL_SRC={gh.GRBL_SRC}", f"BUILD={tmp_path}"],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stdout + r.stderr
    assert (tmp_path / "grbl.hex").stat().st_size > 50_000  # Intel hex of about 30 kB of flash
    cycles = dict(ln.split(": ", 1) for ln in (tmp_path / "homing-cycles.txt").read_text().splitlines())
    assert cycles == {"cycle_0": "((1 << 0) | (1 << 1))", "cycle_1": "(none)", "cycle_2": "(none)"}
    assert "bytes of flash" in r.stdout


def test_conformance_error_and_alarm_sentences_cover_grbls_own_code_tables():
    import csv

    from acquisition.devices import grbl_settings

    tables = (("error_codes_en_US.csv", grbl_settings.ERRORS), ("alarm_codes_en_US.csv", grbl_settings.ALARMS))
    for name, table in tables:
        with open(gh.SHARED_GRBL / "doc" / name, newline="") as fh:
            codes = {int(row[0]) for row in list(csv.reader(fh))[1:] if row}
        assert codes == set(table), name


def test_grbl_conformance_passes_beside_two_cpu_burners():
    """This module's tests whose motion the race broke (or all: ``GONIO_GRBL_LOAD_TESTS=all``; a ``-k``
    expression chooses others) in a child pytest beside two CPU burners: see tests/grbl_under_load.py."""
    from tests.grbl_under_load import run_beside_burners

    if os.environ.get("GONIO_GRBL_UNDER_LOAD"):
        pytest.skip("this is the run beside the burners")
    run_beside_burners()
