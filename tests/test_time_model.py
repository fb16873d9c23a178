"""One time model for the simulator and the planner (reconstruction.instrument.timing): the estimate of `gonio-capture
--check` and of a capture (adaptive rounds estimated as they are planned) is within 5 % of the simulated bench time
the capture takes, on the Dynamixel and the stepper benches; the capture orders its points once."""

from __future__ import annotations

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from acquisition import Bench
from reconstruction.instrument.timing import AxisTiming, MoveTiming, dxl_profile_units, trapezoid_duration
from simulator.world.motion import AxisMotion, TrapezoidProfile

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]


def test_the_simulated_axis_moves_by_the_shared_model():
    """The simulator's profile durations and settled times are the shared model's, for every kind of profile."""
    rng = np.random.default_rng(3)
    for v, a in [(3000.0, 12000.0), (math.inf, 12000.0), (3000.0, math.inf), dxl_profile_units(200, 50)]:
        for x0, x1 in rng.integers(0, 4096, size=(20, 2)):
            p = TrapezoidProfile(float(x0), float(x1), 0.0, v, a)
            assert p.duration == pytest.approx(float(trapezoid_duration(x1 - x0, v, a)), rel=1e-12, abs=1e-15)
            assert float(p.position(p.duration)) == pytest.approx(x1)
            m = AxisMotion(float(x0), settle_time=0.05)
            m.start(float(x1), 0.0, v, a)
            ax = AxisTiming(1.0, 0.0, 1, v, a)
            timing = MoveTiming(ax, ax, arrive_s=0.05)
            assert m.settled_time() == pytest.approx(timing.move_time((x0, 0.0), (x1, 0.0)), abs=1e-12)
    ax = AxisTiming(4096 / 360, 2048, -1, 3000.0, 12000.0)  # goals rounded to whole units, either direction
    t = MoveTiming(ax, ax, 0.1)
    assert t.move_time((0.0, 0.0), (0.0, 0.0)) == 0.0  # nothing moves: no settling either
    pts = rng.uniform(-80, 80, size=(50, 2, 2))
    vec = t.move_times(pts[:, 0], pts[:, 1])
    assert np.allclose(vec, [t.move_time(tuple(a), tuple(b)) for a, b in pts])


def _config(tmp: Path, name: str, over: dict) -> Path:
    """``configs/NAME`` as a simulated bench (the real benches' files with their own [motion] speeds on the
    simulated stepper and the demo material), simulated time as fast as possible, with ``over`` merged in."""
    from tests.helpers import deep_merge

    raw = tomllib.loads((REPO / "configs" / name).read_text())
    if raw["bench"]["transport"] != "simulated":
        raw["bench"].update(transport="simulated", motion="serial" if raw["bench"]["transport"] == "serial"
                            else "dynamixel", dynamixel_port="", serial_port="")
        raw["material"] = tomllib.loads((REPO / "configs" / "simulated.toml").read_text())["material"]
        raw["simulator"] = {"stepper_velocity_deg_s": raw["motion"].get("velocity_deg_s", 60.0),
                            "stepper_acceleration_deg_s2": raw["motion"].get("acceleration_deg_s2", 240.0),
                            "settle_time_s": 0.2}
    raw = deep_merge(raw, {"simulator": {"time_scale": 0.0}, **over})
    p = tmp / f"{Path(name).stem}.toml"
    p.write_text(tomli_w.dumps(raw))
    return p


@pytest.mark.parametrize("name, over, adaptive", [
    ("simulated.toml", {"plan": {"theta_i_deg": [20.0, 50.0], "theta_o_step_deg": 8.0}}, False),
    ("simulated.toml", {"bench": {"motion": "serial"}, "plan": {"theta_i_deg": [35.0], "theta_o_step_deg": 6.0},
                        "simulator": {"stepper_velocity_deg_s": 45.0, "settle_time_s": 0.15}}, False),
    ("serial-bench.toml", {"plan": {"theta_i_deg": [30.0], "theta_o_min_deg": -40.0, "theta_o_max_deg": 70.0,
                                    "adaptive": {"tolerance": 0.02}},
                           "simulator": {"spectrometer": {"wl_step_nm": 40.0}}}, True),
], ids=["dynamixel", "stepper", "stepper-adaptive"])
def test_the_estimate_is_the_simulated_bench_time(tmp_path, name, over, adaptive, capsys):
    from acquisition.cli import main

    cfg = _config(tmp_path, name, over)
    bench = Bench.from_config(cfg)
    plan = bench.plan()
    assert (plan.adaptive is not None) == adaptive
    chk = plan.validate(bench.geometry)
    check = plan.estimate(bench.geometry, bench.cfg.detector.integration_time_s, chk.measurable, cfg=bench.cfg)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    rec = json.loads((out / "capture.json").read_text())
    est, actual = rec["estimate"]["total_s"], rec["totals"]["bench_time_s"]
    # what auto-ranging costs depends on the sample (readings discarded, a dark per new gain or integration time):
    # the estimate cannot foresee it; the record reports it, and the rest is the estimate's
    ranging = rec.get("auto_range", {}).get("overhead_s", 0.0)
    assert actual > 5.0 and est == pytest.approx(actual - ranging, rel=0.05)
    assert ranging < 0.1 * actual
    assert rec["estimate"]["before_refinement_s"] == pytest.approx(check["total_s"], rel=1e-9)  # --check's figure
    run = rec["runs"][-1]
    assert run["estimate_s"] == pytest.approx(est)
    # the calibration as estimated, plus at most what ranging cost (the white reference may range too)
    cal, cal_est = rec["totals"]["calibration_s"], rec["estimate"]["calibration_s"]
    assert 0.95 * cal_est <= cal <= 1.05 * cal_est + ranging
    if adaptive:  # the rounds were estimated as they were planned, and the capture grew by them
        assert rec["estimate"]["refinement_s"] > 0.1 * est and run["samples_new"] > len(chk.measurable)
        assert check["total_s"] < 0.9 * actual
    else:
        assert rec["estimate"]["refinement_s"] == 0.0
        assert check["total_s"] == pytest.approx(actual - ranging, rel=0.05)
        assert rec["estimate"]["motion_s"] == pytest.approx(run["motion_s"], rel=0.05)
    assert f"capture time {actual:.2f} s of bench time, estimated {est:.2f} s" in err  # side by side


def test_with_every_point_auto_ranged_the_estimate_is_within_2_percent_ranging_included(tmp_path, capsys):
    """The demo bench and material (the reference setting, gain 10000, saturates everywhere: every point is read at
    a lower gain), one incidence: the estimate is within 2 % of the simulated bench time with auto-ranging's cost
    in it (the darks at every gain measured with the calibration's and counted; each point's first reading on the
    setting its neighbours predict), where it was 8 % short (three darks measured as the gains were first needed,
    the white reference's 32 repeats read at a clipping gain first, the ladder walked at each edge of the peak).
    The summary names what auto-ranging changed: the gain, not the integration time."""
    from acquisition.cli import main

    cfg = _config(tmp_path, "simulated.toml", {"plan": {"theta_i_deg": [40.0], "theta_o_step_deg": 4.0}})
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    err = capsys.readouterr().err
    rec = json.loads((out / "capture.json").read_text())
    est, actual = rec["estimate"]["total_s"], rec["totals"]["bench_time_s"]
    run = rec["runs"][-1]
    assert rec["auto_range"]["ranged_points"] == run["samples_new"] > 30  # every point ranged
    assert set(rec["auto_range"]["darks"]) >= {f"0.01 s, gain {g}" for g in (1, 10, 100, 1000)}
    assert abs(est - actual) < 0.02 * actual, (est, actual, rec["auto_range"]["overhead_s"])
    assert "read at lower gains (0.01 s, gain" in err and "integration times" not in err
    log = (out / "capture.log").read_text()
    assert "read at lower gains (0.01 s, gain" in log and "read at shorter integration times" not in log


@pytest.mark.slow
def test_in_real_time_the_polling_and_the_software_are_in_the_estimate_too(tmp_path):
    """time_scale = 1: the drivers' polling interval and the software's own time are bench time, as on a real
    bench (the Dynamixel bench's own settings: 0.05 s integration, 0.3 s settling, 0.02 s polling; three
    points, about 6 s)."""
    cfg = _config(tmp_path, "dynamixel-bench.toml", {
        "simulator": {"time_scale": 1.0}, "detector": {"dark_repeats": 8},
        "calibration": {"reference_repeats": 8},
        "plan": {"theta_i_deg": [30.0], "theta_o_min_deg": -40.0, "theta_o_max_deg": 40.0, "theta_o_step_deg": 40.0,
                 "repeats": 4}})
    bench = Bench.from_config(cfg)
    assert bench.geometry.poll_s > 0.02  # 0.02 s polling interval (+ a query) at time scale 1
    r = bench.capture(out=tmp_path / "out", progress=False, handle_signals=False)
    r.raise_for_status()
    assert r.bench_time_s > 3.0
    # auto-ranging's cost depends on the sample and is reported beside the estimate (see above)
    assert r.estimate_s == pytest.approx(r.bench_time_s - r.auto_range_overhead_s, rel=0.05), (
        r.estimate, r.bench_time_s, r.auto_range_overhead_s)


@pytest.mark.parametrize("mode", ["relative", "absolute"])
def test_the_capture_orders_its_points_once_from_where_it_starts_them(tmp_path, monkeypatch, mode):
    """The estimate runs the capture's own plan from where the capture starts the points (the white reference, or
    park as the bench reads it back), so the capture reuses its order instead of ordering again."""
    from acquisition.plans import ordering

    calls = []
    real = ordering._order
    monkeypatch.setattr(ordering, "_order", lambda *a, **k: calls.append(a[2]) or real(*a, **k))
    ordering._ORDERED.clear()
    over = {"plan": {"theta_i_deg": [30.0, 60.0], "theta_o_step_deg": 10.0},
            "axes": {"detector": {"park_deg": 44.97}}}  # not a whole number of units
    if mode == "absolute":
        over["calibration"] = {"mode": "absolute", "source_power": 1e6, "detector_solid_angle_sr": 1e-3}
    cfg = _config(tmp_path, "simulated.toml", over)
    with Bench.from_config(cfg) as bench:
        r = bench.capture(out=tmp_path / "out", progress=False, handle_signals=False)
    r.raise_for_status()
    c, g = bench.cfg.calibration, bench.geometry
    start = (c.reference_theta_i_deg, c.reference_theta_o_deg) if mode == "relative" else (
        g.quantise(g.light, g.park[0]), g.quantise(g.detector, g.park[1]))
    assert calls == [start]  # once, from there
    assert r.estimate_s == pytest.approx(r.bench_time_s - r.auto_range_overhead_s, rel=0.05)


def test_a_resumed_capture_estimates_what_is_left_and_counts_the_runs_before(tmp_path):
    """A run stopped by a vanishing port, then resumed: the resume's estimate is of the points left (from the
    slice's own calibration), and estimate.total_s adds the earlier run's bench time, beside totals.bench_time_s."""
    from acquisition.cli import main

    over = {"plan": {"theta_i_deg": [30.0], "theta_o_step_deg": 4.0}}
    cfg = _config(tmp_path, "simulated.toml", {**over, "simulator": {"faults": {"port_vanish_after_s": 6.0}}})
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    cfg = _config(tmp_path, "simulated.toml", over)
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0
    rec = json.loads((out / "capture.json").read_text())
    first, second = rec["runs"]
    assert first["status"] == "failed" and 0 < first["samples_new"] and second["samples_before"] > 0
    assert rec["estimate"]["previous_runs_s"] == pytest.approx(first["bench_time_s"])
    assert rec["estimate"]["this_run_s"] == pytest.approx(second["bench_time_s"], rel=0.05)
    assert rec["estimate"]["total_s"] == pytest.approx(rec["totals"]["bench_time_s"], rel=0.05)
    assert rec["estimate"]["calibration_s"] < 0.5 * first["calibration_s"]  # no new white reference, one dark
