"""The warm-up check before the calibration ([calibration].warmup_readings, warmup_interval_s, warmup_max_drift,
warmup_timeout_s) on a simulated lamp that warms up ([simulator].source_warmup_depth, source_warmup_s): the capture
waits until the white reference's reading holds still, or stops with one line that says why."""

from __future__ import annotations

import math

from acquisition.cli import main
from tests.test_acq_support import make_raw, read, write_config

#: a lamp 5 % dim at power-up, warming up with a time constant of 60 s
LAMP = {"simulator": {"source_warmup_depth": 0.05, "source_warmup_s": 60.0}}
PLAN = {"plan": {"theta_i_deg": [30.0], "theta_o_min_deg": 0.0, "theta_o_max_deg": 40.0, "theta_o_step_deg": 4.0,
                 "repeats": 100, "order": "naive"}}  # 11 points of 1 s: 0 deg first, 40 deg last


def warm(**keys) -> dict:
    return {"calibration": {"warmup_readings": 3, "warmup_interval_s": 10.0, "warmup_max_drift": 0.002, **keys}}


def test_the_calibration_waits_for_the_source_to_warm_up(tmp_path, capsys):
    out = tmp_path / "out"
    cfg = write_config(tmp_path / "w.toml", make_raw(PLAN, LAMP, warm()))
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 0
    log = (out / "capture.log").read_text()
    line = next(x for x in log.splitlines() if "warm-up check: the source is steady" in x)
    t = float(line.split(" after ")[1].split(" s")[0])
    # three readings 10 s apart (t - 20 s .. t) agree within 0.2 % once 5 % exp(-(t - 20 s) / 60 s) (1 - exp(-20 s
    # / 60 s)) < 0.2 % (the check's clock starts a few seconds into the bench's, after the dark)
    t_needed = 20.0 - 60.0 * math.log(0.002 / (0.05 * (1 - math.exp(-20.0 / 60.0))))
    assert t_needed - 15.0 <= t <= t_needed + 15.0, (t, t_needed)
    warmed = read(out / "slice.csv")
    assert len(warmed) == 11
    # without the check the white reference is read at once, on a lamp still warming up: the later a point, the
    # brighter the lamp and the higher it reads (relative to the warmed-up capture)
    out2 = tmp_path / "out2"
    cfg2 = write_config(tmp_path / "n.toml", make_raw(PLAN, LAMP))
    assert main(["--config", str(cfg2), "--out", str(out2), "--no-progress"]) == 0
    assert "warm-up check" not in (out2 / "capture.log").read_text()
    ratio = read(out2 / "slice.csv").values[:, 0] / warmed.values[:, 0]
    assert ratio[-1] > 1.008 and ratio[-1] - ratio[0] > 0.006, ratio


def test_a_source_that_does_not_settle_stops_with_one_line(tmp_path, capsys):
    out = tmp_path / "out"
    cfg = write_config(tmp_path / "w.toml", make_raw(PLAN, LAMP, warm(warmup_timeout_s=60.0)))
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    err = capsys.readouterr().err
    assert "the source has not warmed up: its white-reference reading still drifts" in err
    assert "[calibration].warmup_max_drift = 0.2 %" in err and "warmup_timeout_s = 60" in err
    assert "Traceback" not in err


def test_ratio_readings_take_the_lamps_warm_up_out_without_waiting(tmp_path, capsys):
    """A lamp 10 % dim at power-up warming with a 60 s time constant, read at once: with [detector].monitor = true
    (gonio-sim's controller sends the monitor's sum as the board built with MONITOR=1 does: after the repeats, so a
    lamp brightening during a 1 s reading leaves its rise over half a reading) the slice is the steady lamp's within
    0.2 % at every point; without it, the later the point the brighter (as in the test above)."""
    lamp = {"simulator": {"source_warmup_depth": 0.1, "source_warmup_s": 60.0}}
    runs = {}
    for name, overs in (("steady", ()), ("ratio", (lamp, {"detector": {"monitor": True}})), ("plain", (lamp,))):
        cfg = write_config(tmp_path / f"{name}.toml", make_raw(PLAN, *overs))
        assert main(["--config", str(cfg), "--out", str(tmp_path / name), "--no-progress"]) == 0, \
            capsys.readouterr().err
        runs[name] = read(tmp_path / name / "slice.csv").values[:, 0]
    ratio, plain = runs["ratio"] / runs["steady"], runs["plain"] / runs["steady"]
    assert abs(ratio - 1).max() < 0.002, ratio
    assert plain[-1] > 1.015 and plain[-1] - plain[0] > 0.01, plain
    assert read(tmp_path / "ratio" / "slice.csv").meta["calibration"]["monitor_ratio"] is True
