"""Fault storms (issue 11): each fault kind of the simulator at rates 0.01, 0.05 and 0.2. Every run completes or
stops with exit status 1 and resumable data (never a traceback, never a sample lost, changed or taken twice),
and repeated ``--resume`` with the same config completes the capture: the resumed runs draw new faults
(``gonio-sim serve --attempt N``) instead of replaying the ones that stopped the run before.

Corrupt bytes are a rate per byte of every reply, so their cost grows with the reply's length: at 0.05 per byte
half of all Dynamixel status packets arrive corrupt, which takes more than the default 3 retries per transaction
(the storm sets [motion].retries = 12, as a noisy line needs); at 0.2 per byte 97 % of them do, and no retry
budget lets a capture through in useful time: there the storm checks only that every run stops safely with its
data intact.
"""

from __future__ import annotations

import numpy as np
import pytest

from acquisition.cli import main
from tests.helpers import planned
from tests.test_acq_support import integration_times, keys, make_raw, read, write_config, zscores

RATES = (0.01, 0.05, 0.2)
PLAN = {"theta_o_step_deg": 10.0}  # 14 measurable points at theta_i = 30

STORMS = (
    [("drop_reply_rate", r, "dynamixel", {"serial_comm_faults": True}, {}, True) for r in RATES]
    + [("corrupt_byte_rate", 0.01, "dynamixel", {"serial_comm_faults": True}, {}, True),
       ("corrupt_byte_rate", 0.05, "dynamixel", {}, {"motion": {"retries": 12}}, True),
       ("corrupt_byte_rate", 0.2, "dynamixel", {}, {}, False)]
    + [("overload_rate", r, "dynamixel", {}, {}, True) for r in RATES]
    + [("stall_rate", r, "serial", {}, {}, True) for r in RATES]
    + [("saturate_rate", r, "dynamixel", {}, {}, True) for r in RATES]
)

MAX_RUNS = 40


def storm_raw(kind: str, rate: float, motion: str, faults: dict, over: dict) -> dict:
    return make_raw({"bench": {"motion": motion}, "plan": PLAN, "simulator": {"faults": {kind: rate, **faults}}},
                    over)


def run_storm(tmp_path, capsys, raw: dict, runs: int) -> tuple[list[int], dict, int]:
    """Capture, then --resume with the same config until it completes (at most ``runs`` runs). After every
    run the slice must read back with every earlier sample unchanged. Returns (exit codes, samples, lost)."""
    cfg = write_config(tmp_path / "storm.toml", raw)
    out = tmp_path / "out"
    plan = set(planned(cfg))
    codes: list[int] = []
    seen: dict[tuple[float, float], float] = {}
    lost = 0
    for run in range(runs):
        code = main(["--config", str(cfg), "--out", str(out), "--no-progress"] + (["--resume"] if run else []))
        err = capsys.readouterr().err
        codes.append(code)
        assert "Traceback" not in err and code in (0, 1), err
        if (out / "slice.csv").exists():
            s = read(out / "slice.csv")  # consistent: the reader rejects duplicates and torn rows are cut
            now = dict(zip(keys(s), s.values[:, 0].tolist(), strict=True))
            assert set(now) <= plan
            lost += sum(k not in now or now[k] != v for k, v in seen.items())
            seen = now
        if code == 0:
            break
        assert "--resume" in err and ("safely in" in err or "No sample was captured yet" in err), err
    return codes, seen, lost


@pytest.mark.slow
@pytest.mark.parametrize("kind, rate, motion, faults, over, completes", STORMS,
                         ids=[f"{s[0]}-{s[1]}" for s in STORMS])
def test_fault_storm(tmp_path, capsys, kind, rate, motion, faults, over, completes):
    raw = storm_raw(kind, rate, motion, faults, over)
    codes, samples, lost = run_storm(tmp_path, capsys, raw, MAX_RUNS if completes else 3)
    assert lost == 0
    cfg = tmp_path / "storm.toml"
    if not completes:
        assert codes == [1, 1, 1]  # stopped safely every time, data intact
        return
    assert codes[-1] == 0, f"{kind} {rate}: not complete after {len(codes)} runs: {codes}"
    s = read(tmp_path / "out" / "slice.csv")
    assert sorted(keys(s)) == planned(cfg)
    z, _ = zscores(raw, s, integration_times(tmp_path / "out", s))
    assert np.all(np.abs(z) < 6.0), (kind, rate, np.abs(z).max())  # no corrupt reading slipped through
    if rate == 0.2 and kind in ("overload_rate", "stall_rate"):
        assert len(codes) > 1  # the faults did stop runs, and the resumes went on from there


@pytest.mark.slow
def test_a_resume_does_not_replay_the_faults_that_stopped_the_run(tmp_path, capsys):
    """The issue's case: 1 % corrupt bytes on both ports. With seed 13 (6 was the issue's, until the board's
    replies and the questions a capture asks changed the fault streams again) the first run fails before its first
    sample (during the calibration); a resume that replayed the first run's random streams failed there every time
    (no sample was ever captured); with --attempt 1 it draws new faults and completes."""
    raw = make_raw({"plan": PLAN, "simulator": {"seed": 13, "faults": {"corrupt_byte_rate": 0.01,
                                                                      "serial_comm_faults": True}}})
    cfg = write_config(tmp_path / "seed13.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    assert "No sample was captured yet" in capsys.readouterr().err
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0
    assert sorted(keys(read(out / "slice.csv"))) == planned(cfg)
