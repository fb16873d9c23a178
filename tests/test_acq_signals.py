"""Interrupting captures: SIGTERM and SIGINT park the arms and exit non-zero with a resume hint; SIGKILL at random
moments, resumed each time, ends with exactly the samples of an uninterrupted run."""

from __future__ import annotations

import os
import signal
import time

import numpy as np
import pytest

from tests.helpers import planned
from tests.test_acq_support import keys, make_raw, popen_capture, read, run_capture, write_config, zscores

SLOW = {"simulator": {"time_scale": 8.0}}  # ~1.2 s of wall time for the 26-point plan


def rows(path) -> int:
    try:
        return sum(1 for line in path.read_text().splitlines() if line and line[0].isdigit())
    except FileNotFoundError:
        return 0


def wait_for_rows(path, n, proc, timeout=30.0) -> None:
    t_end = time.monotonic() + timeout
    while rows(path) < n:
        assert proc.poll() is None, proc.communicate()
        assert time.monotonic() < t_end, "capture made no progress"
        time.sleep(0.01)


@pytest.mark.parametrize("sig, code", [(signal.SIGTERM, 143), (signal.SIGINT, 130)])
def test_signal_parks_torque_off_and_resumes(tmp_path, sig, code):
    cfg = write_config(tmp_path / "slow.toml", make_raw(SLOW))
    out = tmp_path / "out"
    p = popen_capture("--config", str(cfg), "--out", str(out), "--no-progress")
    wait_for_rows(out / "slice.csv", 4, p)
    p.send_signal(sig)
    _, err = p.communicate(timeout=30)
    assert p.returncode == code, err
    assert f"interrupted by {signal.Signals(sig).name}" in err
    assert f"gonio-capture --config {cfg} --out {out} --resume" in err
    log = (out / "capture.log").read_text()
    assert "arms parked at (0, 45)" in log and "motion released (torque off)" in log
    n1 = rows(out / "slice.csv")
    assert 4 <= n1 < len(planned(cfg))
    sim_log = (out / "simulator.log").read_text()
    assert "stopped; total simulated time" in sim_log  # the simulator was shut down cleanly, not orphaned
    fast = write_config(tmp_path / "fast.toml", make_raw())
    r = run_capture("--config", str(fast), "--out", str(out), "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    s = read(out / "slice.csv")
    assert sorted(keys(s)) == planned(fast)


def test_sigkill_at_random_moments_then_resume(tmp_path):
    """Kill -9 the capture several times at random moments, resume each time: the final set of samples equals
    an uninterrupted run's, none twice, and the values agree with the ground truth."""
    raw_slow = make_raw(SLOW)
    cfg = write_config(tmp_path / "slow.toml", raw_slow)
    out = tmp_path / "out"
    seed = 20260611  # the kill delays; the moments they hit still vary with the machine's speed
    rng = np.random.default_rng(seed)
    delays = []
    counts = []
    n_plan = len(planned(cfg))
    for k in range(4):
        args = ["--config", str(cfg), "--out", str(out), "--no-progress"] + (["--resume"] if k else [])
        p = popen_capture(*args)
        if k == 0:  # during start-up, calibration or the first samples
            delay = float(rng.uniform(0.2, 0.8))
            time.sleep(delay)
        else:  # mid-capture: once it made progress, at a random moment (possibly mid-write)
            wait_for_rows(out / "slice.csv", min(counts[-1] + 1, n_plan), p)
            delay = float(rng.uniform(0.0, 0.25))
            time.sleep(delay)
        delays.append(round(delay, 3))
        if p.poll() is None:
            os.kill(p.pid, signal.SIGKILL)
        p.communicate(timeout=30)
        counts.append(rows(out / "slice.csv"))
    # the orphaned simulators notice their parent is gone and exit
    t_end = time.monotonic() + 5.0
    while "parent process gone" not in (out / "simulator.log").read_text() and time.monotonic() < t_end:
        time.sleep(0.05)
    fast = make_raw()
    cfg_fast = write_config(tmp_path / "fast.toml", fast)
    r = run_capture("--config", str(cfg_fast), "--out", str(out), "--resume", "--no-progress")
    assert r.returncode == 0, (f"seed {seed}", delays, counts, r.stderr)
    s = read(out / "slice.csv")  # rejects duplicate samples; a torn last line was cut before appending
    reference = tmp_path / "uninterrupted"
    r2 = run_capture("--config", str(cfg_fast), "--out", str(reference), "--no-progress")
    assert r2.returncode == 0, r2.stderr
    assert sorted(keys(s)) == sorted(keys(read(reference / "slice.csv"))) == planned(cfg_fast), (
        f"seed {seed}", delays, counts)
    z, _ = zscores(fast, s)
    assert np.all(np.abs(z) < 5.0), (f"seed {seed}", delays, counts)
    assert counts == sorted(counts), (f"seed {seed}", delays, counts)  # never lost a sample
    print("seed", seed, "kill delays", delays, "samples after each kill", counts)
