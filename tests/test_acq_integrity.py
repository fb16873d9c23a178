"""Nothing lost, nothing mixed (issue 11): one capture per output folder (an flock, taken over from a killed
holder), resumes that append under the right columns and refuse a changed experiment, double signals, a full
disk and read-only outputs, all without a traceback and with the data resumable."""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest

from acquisition.calibration import Reading, pool
from acquisition.cli import main
from acquisition.devices.autorange import read_clean
from acquisition.devices.serial_link import SerialDetector
from acquisition.errors import CommError
from acquisition.run.lock import LOCK_NAME
from tests.helpers import planned, unprivileged
from tests.test_acq_signals import rows, wait_for_rows
from tests.test_acq_support import (
    REPO,
    integration_times,
    keys,
    make_raw,
    popen_capture,
    read,
    run_capture,
    write_config,
    zscores,
)

SLOW = {"simulator": {"time_scale": 8.0}}  # ~1.2 s of wall time for the 26-point plan


def one_line(err: str) -> bool:
    return err.count("\n") == 1 and "Traceback" not in err


# --- one capture per folder -----------------------------------------------------------------------------------


@pytest.mark.slow
def test_two_captures_on_one_out_the_second_refuses_at_once(tmp_path):
    cfg = write_config(tmp_path / "slow.toml", make_raw(SLOW))
    out = tmp_path / "out"
    a = popen_capture("--config", str(cfg), "--out", str(out), "--no-progress")
    b = popen_capture("--config", str(cfg), "--out", str(out), "--no-progress")  # started together
    t_end = time.monotonic() + 20.0
    while a.poll() is None and b.poll() is None:
        assert time.monotonic() < t_end, "neither capture refused"
        time.sleep(0.01)
    loser, winner = (a, b) if a.poll() is not None else (b, a)
    loser_err = loser.stderr.read()
    assert loser.returncode == 2, loser_err
    wait_for_rows(out / "slice.csv", 2, winner)
    c = run_capture("--config", str(cfg), "--out", str(out), "--resume", "--no-progress")  # a resume of it
    # refused, not queued: a resume that waited for the lock would run once the winner is done and exit 0
    assert c.returncode == 2
    for err in (loser_err, c.stderr):
        assert one_line(err), err
        assert f"--out {out}: in use by another capture (PID {winner.pid}, holding {out / LOCK_NAME})" in err
    assert winner.wait(30) == 0, winner.stderr.read()
    s = read(out / "slice.csv")  # the reader rejects duplicate samples
    assert sorted(keys(s)) == planned(cfg)
    runs = json.loads((out / "capture.json").read_text())["runs"]
    assert [r["pid"] for r in runs] == [winner.pid]  # the refused ones wrote nothing
    assert not (out / LOCK_NAME).exists()  # released and removed at the end


@pytest.mark.slow
def test_kill_9_of_the_lock_holder_then_resume(tmp_path):
    cfg = write_config(tmp_path / "slow.toml", make_raw(SLOW))
    out = tmp_path / "out"
    p = popen_capture("--config", str(cfg), "--out", str(out), "--no-progress")
    wait_for_rows(out / "slice.csv", 4, p)
    os.kill(p.pid, signal.SIGKILL)
    p.communicate(timeout=30)
    assert (out / LOCK_NAME).read_text().strip() == str(p.pid)  # the stale lock file names the dead holder
    before = read(out / "slice.csv")
    fast = write_config(tmp_path / "fast.toml", make_raw())
    r = run_capture("--config", str(fast), "--out", str(out), "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert f"took over {out / LOCK_NAME} from PID {p.pid}, which ended without releasing it" in \
        (out / "capture.log").read_text()
    s = read(out / "slice.csv")
    assert sorted(keys(s)) == planned(fast)
    kept = {k: v for k, v in zip(keys(s), s.values[:, 0], strict=True)}
    assert all(kept[k] == v for k, v in zip(keys(before), before.values[:, 0], strict=True))


def test_in_process_captures_of_one_folder_exclude_each_other(tmp_path):
    """The lock is an flock on an open file: a second engine in the same process is refused as well."""
    from acquisition import Bench
    from acquisition.run.lock import OutDirLocked, OutLock

    out = tmp_path / "out"
    out.mkdir()
    held = OutLock(out)
    held.acquire()
    bench = Bench.from_config(write_config(tmp_path / "c.toml", make_raw()))
    with pytest.raises(OutDirLocked, match=rf"in use by another capture \(PID {os.getpid()}"):
        bench.capture(out=out, progress=False)
    assert not bench.is_open and not (out / "slice.csv").exists()
    held.release()
    assert bench.capture(out=out, progress=False).ok


# --- resumes that cannot mix data -----------------------------------------------------------------------------


def partial_capture(tmp_path: Path, capsys) -> tuple[Path, dict]:
    raw = make_raw({"simulator": {"faults": {"port_vanish_after_s": 5.8, "vanish_ports": "dynamixel"}}})
    cfg = write_config(tmp_path / "vanish.toml", raw)
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 1
    capsys.readouterr()
    assert 0 < len(read(out / "slice.csv")) < len(planned(cfg))
    return out, make_raw()


@pytest.mark.slow
@pytest.mark.parametrize("newline", ["\n", "\r\n"])
def test_resume_after_a_column_reorder_appends_under_the_right_columns(tmp_path, capsys, newline):
    out, raw = partial_capture(tmp_path, capsys)
    path = out / "slice.csv"
    before = read(path)
    lines = path.read_text().splitlines()
    order = [4, 2, 5, 0, 3, 1]  # another tool rewrote the file: columns shuffled (and maybe CRLF)
    lines[2:] = [",".join(line.split(",")[k] for k in order) for line in lines[2:]]
    path.write_bytes((newline.join(lines) + newline).encode())
    header = lines[2]
    cfg = write_config(tmp_path / "fixed.toml", raw)
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0
    s = read(path)
    assert sorted(keys(s)) == planned(cfg)
    assert path.read_bytes().decode().split(newline)[2] == header  # the file keeps its own layout
    for k, v in zip(keys(before), before.values[:, 0], strict=True):
        assert s.values[keys(s).index(k), 0] == v
    z, _ = zscores(raw, s, integration_times(out, s))  # a value under the wrong column would be far off
    assert np.all(np.abs(z) < 5.0) and np.all(s.repeats == 4) and np.all(s.unix_time_s > 1.7e9)


def test_resume_refuses_a_slice_whose_columns_are_not_the_detectors(tmp_path, capsys):
    out, raw = partial_capture(tmp_path, capsys)
    path = out / "slice.csv"
    text = path.read_text().replace("value_std", "550nm_std").replace(",value,", ",550nm,")
    path.write_text(text)
    cfg = write_config(tmp_path / "fixed.toml", raw)
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cannot resume" in err and "['550nm']" in err and "nothing was moved" in err, err
    assert path.read_text() == text


SWAPPED = {"name": "white-paint", "lobes": [{"type": "lambert", "albedo": 0.8}]}


def swapped_sample_simulator(tmp_path: Path) -> Path:
    """A ``[bench].simulator_command`` (a setting that cannot change a sample) that serves the bench file with
    another sample mounted: its [material] replaced by SWAPPED, everything else as given. So the capture's config,
    and its fingerprint, stay the same while the sample on the (simulated) bench changes, as on a real bench."""
    script = tmp_path / "swapped-sim"
    script.write_text(f"""#!{sys.executable}
import os, sys, tomllib, tomli_w
args = sys.argv[1:]
k = args.index("--config") + 1
raw = tomllib.loads(open(args[k], encoding="utf-8").read())
raw["material"] = {SWAPPED!r}
with open(args[k] + ".swapped.toml", "w", encoding="utf-8") as fh:
    fh.write(tomli_w.dumps(raw))
args[k] += ".swapped.toml"
os.execv(sys.executable, [sys.executable, "-m", "simulator.cli", *args])
""")
    script.chmod(0o755)
    return script


@pytest.mark.slow
def test_a_resume_with_another_sample_on_the_bench_is_refused_unless_forced(tmp_path, capsys):
    """Issue 22, item 4: a capture stopped part-way is resumed with another sample on the bench (the config the
    same): the last two recorded points are measured again first, read ~5 x the recorded values, and the resume
    is refused (exit 2) with both readings and what to do, before anything is appended; ``--resume --force``
    goes on, and capture.json records both readings and that it was forced. The same sample resumes as before
    (its points read as recorded), and with --force a changed [material] (the simulated sample) passes the
    fingerprint too, recorded."""
    out, raw = partial_capture(tmp_path, capsys)
    for name in ("same", "material"):
        shutil.copytree(out, tmp_path / name)
    before = (out / "slice.csv").read_bytes()
    n_before = len(read(out / "slice.csv"))
    swapped = write_config(tmp_path / "swapped.toml", make_raw({"bench": {
        "simulator_command": str(swapped_sample_simulator(tmp_path))}}))
    assert main(["--config", str(swapped), "--out", str(out), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert "cannot resume: the sample on the bench does not read as the one recorded: at (30, " in err, err
    assert "1/sr then and" in err and "1/sr now" in err and "more than 5 sigma + 5 % apart" in err
    assert f"gonio-capture --config {swapped} --out {out} --resume --force" in err and "Traceback" not in err
    assert (out / "slice.csv").read_bytes() == before  # nothing appended
    run = json.loads((out / "capture.json").read_text())["runs"][-1]
    check = run["sample_check"]
    assert run["status"] == "failed" and check["agree"] is False and check["forced"] is False
    assert len(check["points"]) == 2 and all(p["now"] > 3 * p["recorded"] for p in check["points"]), check
    assert main(["--config", str(swapped), "--out", str(out), "--resume", "--force", "--no-progress"]) == 0
    s = read(out / "slice.csv")
    assert sorted(keys(s)) == planned(swapped)
    rec = json.loads((out / "capture.json").read_text())
    assert rec["status"] == "complete" and rec["runs"][-1]["sample_check"]["forced"] is True
    assert "going on as --force asks" in (out / "capture.log").read_text()
    assert float(np.median(s.values[n_before:, 0])) > 3 * float(np.median(s.values[:n_before, 0]))  # two samples
    # the same sample: its points read as recorded, the resume goes on
    fixed = write_config(tmp_path / "fixed.toml", raw)
    assert main(["--config", str(fixed), "--out", str(tmp_path / "same"), "--resume", "--no-progress"]) == 0
    check = json.loads((tmp_path / "same" / "capture.json").read_text())["runs"][-1]["sample_check"]
    assert check["agree"] is True and check["forced"] is False and len(check["points"]) == 2
    # another [material] in the config itself: the fingerprint refuses it, --force accepts it as a sample change
    changed = write_config(tmp_path / "changed.toml", make_raw({"material": SWAPPED}))
    capsys.readouterr()
    assert main(["--config", str(changed), "--out", str(tmp_path / "material"), "--resume", "--no-progress"]) == 2
    assert "[material].lobes[0].albedo" in capsys.readouterr().err
    assert main(["--config", str(changed), "--out", str(tmp_path / "material"), "--resume", "--force",
                 "--no-progress"]) == 0
    check = json.loads((tmp_path / "material" / "capture.json").read_text())["runs"][-1]["sample_check"]
    assert check["forced"] is True and "[material].lobes[0].albedo" in check["config_changes"]


@pytest.fixture(scope="module")
def complete_capture(tmp_path_factory):
    d = tmp_path_factory.mktemp("complete")
    raw = make_raw({"plan": {"theta_o_step_deg": 20.0}})
    cfg = write_config(d / "base.toml", raw)
    assert main(["--config", str(cfg), "--out", str(d / "out"), "--no-progress"]) == 0
    return d / "out", raw


MEANINGFUL = [
    ({"material": {"lobes": [{"type": "lambert", "albedo": [0.05, 0.10, 0.40]},
                             {"type": "ggx", "alpha": 0.3, "specular": [0.9, 0.9, 0.9], "f0": 0.04}]}},
     ["[material].lobes[1].alpha: 0.15 -> 0.3"]),
    ({"simulator": {"gain": 2.0}}, ["[simulator].gain: 1.0 -> 2.0"]),
    ({"simulator": {"source_power": 2.0e6}}, ["[simulator].source_power: 1000000.0 -> 2000000.0"]),
    ({"calibration": {"reference_reflectance": 0.95}}, ["[calibration].reference_reflectance: 0.99 -> 0.95"]),
    ({"calibration": {"reference_theta_o_deg": 15.0}}, ["[calibration].reference_theta_o_deg: 10.0 -> 15.0"]),
    ({"detector": {"type": "spectrometer"}}, ['[detector].type: "photodiode" -> "spectrometer"']),
    ({"detector": {"integration_time_s": 0.02}}, ["[detector].integration_time_s: 0.01 -> 0.02"]),
    ({"detector": {"saturation": 60000}}, ["[detector].saturation: 65535.0 -> 60000.0"]),
    ({"plan": {"theta_o_step_deg": 10.0}}, ["different plan", "[plan].theta_o_step_deg: 20.0 -> 10.0"]),
    ({"plan": {"theta_o_max_deg": 60.0}}, ["different plan", "[plan].theta_o_max_deg: 70.0 -> 60.0"]),
    ({"plan": {"repeats": 8}}, ["[plan].repeats: 4.0 -> 8.0"]),
    ({"axes": {"detector": {"zero_offset": 2050}}}, ["[axes.detector].zero_offset: 2048.0 -> 2050.0"]),
    ({"motion": {"settle_s": 0.2}}, ["[motion].settle_s: 0.05 -> 0.2"]),
    ({"bench": {"motion": "serial"}}, ['[bench].motion: "dynamixel" -> "serial"']),
    ({"simulator": {"gain": 2.0, "read_noise": 9.0}, "plan": {"theta_o_min_deg": -60.0}},
     ["different plan and configuration", "[simulator].gain: 1.0 -> 2.0", "[simulator].read_noise: 5.0 -> 9.0",
      "[plan].theta_o_min_deg: -70.0 -> -60.0"]),
]


@pytest.mark.parametrize("over, named", MEANINGFUL, ids=[m[1][-1].split(":")[0] for m in MEANINGFUL])
def test_resume_with_a_meaningful_change_is_refused_naming_each_key(tmp_path, capsys, complete_capture, over,
                                                                    named):
    src, raw = complete_capture
    out = tmp_path / "out"
    shutil.copytree(src, out)
    before = {p.name: p.read_bytes() for p in out.iterdir()}
    cfg = write_config(tmp_path / "changed.toml", make_raw({"plan": {"theta_o_step_deg": 20.0}}, over))
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 2
    err = capsys.readouterr().err
    assert f"cannot resume: {out / 'slice.csv'} was captured with a different" in err
    assert all(n in err for n in named), err
    assert err.count("\n") == 1 and "nothing was moved" in err
    assert {p.name: p.read_bytes() for p in out.iterdir()} == before  # nothing opened, written or logged


def test_resume_with_harmless_changes_is_allowed_and_logged(tmp_path, capsys, complete_capture):
    src, _ = complete_capture
    out = tmp_path / "out"
    shutil.copytree(src, out)
    cfg = write_config(tmp_path / "harmless.toml", make_raw(
        {"plan": {"theta_o_step_deg": 20.0}, "motion": {"poll_interval_s": 0.02, "timeout_s": 30.0},
         "simulator": {"seed": 7, "time_scale": 2.0, "faults": {"drop_reply_rate": 0.01}}}))
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0
    assert "already complete" in capsys.readouterr().err
    log = (out / "capture.log").read_text()
    for change in ("[motion].poll_interval_s: 0.01 -> 0.02", "[motion].timeout_s: 20.0 -> 30.0",
                   "[simulator].seed: 1.0 -> 7.0", "[simulator].time_scale: 0.0 -> 2.0",
                   '[simulator.faults].drop_reply_rate: 0.0 -> 0.01'):
        assert change in log, log
    assert "resuming with changed setting(s) that cannot change a sample" in log


def test_the_fingerprint_is_in_the_slice_metadata(complete_capture):
    out, _ = complete_capture
    meta = read(out / "slice.csv").meta
    fp = meta["config_fingerprint"]
    assert fp["[simulator].gain"] == 1.0 and fp["[material].lobes[1].alpha"] == 0.15
    assert fp["[calibration].reference_theta_o_deg"] == 10.0 and fp["[detector].integration_time_s"] == 0.01
    assert "[motion].poll_interval_s" in meta["config_settings"] and "[motion].poll_interval_s" not in fp


# --- resumed runs continue the simulator's random streams -------------------------------------------------------


@pytest.mark.slow
def test_a_resumed_run_draws_new_faults_and_noise(tmp_path, capsys):
    from simulator.bench import VirtualBench
    from simulator.config import load_config as sim_config

    cfg = sim_config(write_config(tmp_path / "f.toml", make_raw({"simulator": {"faults": {"overload_rate": 0.5}}})))
    draws = [[VirtualBench(cfg, attempt=a).motion_faults.rng.random() for _ in range(1)] for a in (0, 0, 1, 2)]
    assert draws[0] == draws[1] and len({d[0] for d in draws[1:]}) == 3  # attempt 0 is the seed's own stream
    out, _ = partial_capture(tmp_path, capsys)
    cfg2 = write_config(tmp_path / "fixed.toml", make_raw())
    assert main(["--config", str(cfg2), "--out", str(out), "--resume", "--no-progress"]) == 0
    sim_log = (out / "simulator.log").read_text()
    assert "attempt=0" in sim_log and "attempt=1" in sim_log


def test_pieces_of_a_reading_pool_exactly():
    rng = np.random.default_rng(3)
    x = rng.normal(100.0, 5.0, size=(32, 2))
    whole = Reading(x.mean(0), x.std(0, ddof=1), 32)
    parts = pool(Reading(x[:13].mean(0), x[:13].std(0, ddof=1), 13), Reading(x[13:].mean(0), x[13:].std(0, ddof=1), 19))
    np.testing.assert_allclose(parts.mean, whole.mean, rtol=1e-12)
    np.testing.assert_allclose(parts.std, whole.std, rtol=1e-12)
    assert parts.n == 32


def test_a_reading_whose_long_reply_keeps_failing_is_read_in_pieces():
    class Link:
        name, port, dead = "serial controller", "/dev/pts/x", False

        def __init__(self) -> None:
            self.sent: list[int] = []
            self.answered: list[int] = []

        def command(self, cmd, expect_s=0.0, check=None, busy_ok=False):
            n = int(cmd.split()[1])
            self.sent.append(n)
            if n > 4:  # a long reply: a corrupt byte every time
                raise CommError(f"no valid reply to {cmd!r} after 4 attempts")
            self.answered.append(n)
            v = np.full(n, 1000.0) + np.arange(n)
            fields = {"n": str(n), "mean": f"{v.mean():.6f}", "std": f"{v.std(ddof=1) if n > 1 else 0.0:.6f}",
                      "sat": "0", "values": ",".join(f"{x:g}" for x in v)}
            from acquisition.devices.serial_link import Reply

            check(Reply(fields, []))

    link = Link()
    det = SerialDetector(link, "photodiode", 0.01, 65535.0)  # type: ignore[arg-type]
    rd = det.read(32)
    assert rd.n == 32 and link.sent[:3] == [32, 16, 8] and link.answered == [4] * 8
    np.testing.assert_allclose(rd.mean, [1001.5])  # the pieces pooled: 8 readings of 1000..1003
    with pytest.raises(CommError):  # a port that is gone is not read in pieces
        link.dead = True
        det.read(32)
    assert link.sent[-1] == 32


def test_transient_clips_are_read_around_and_real_saturation_is_not():
    rng = np.random.default_rng(0)

    def transient(n: int) -> Reading:  # 20 % of repeats clip at random
        sat = int(np.sum(rng.random(n) < 0.2))
        return Reading(np.array([1000.0 + 64535.0 * sat / n]), np.array([1.0]), n, sat)

    for _ in range(20):
        rd, commands, repeats = read_clean(transient, 32, retries=3)
        assert rd.n == 32 and repeats <= 32 * 5 + 3 * 32
    assert sum(read_clean(transient, 32, retries=3)[0].saturated == 0 for _ in range(50)) >= 45  # ~95 %
    full, commands, _ = read_clean(lambda n: Reading(np.array([65535.0]), np.zeros(1), n, n), 32)
    assert full.saturated == 32 and commands == 1


# --- signals ------------------------------------------------------------------------------------------------


@pytest.mark.slow
@pytest.mark.parametrize("first, second, code, gap", [(signal.SIGTERM, signal.SIGTERM, 143, 0.0),
                                                      (signal.SIGINT, signal.SIGINT, 130, 0.03),
                                                      (signal.SIGTERM, signal.SIGINT, 143, 0.1)])
def test_a_second_signal_while_stopping_is_no_traceback_and_keeps_the_status(tmp_path, first, second, code, gap):
    cfg = write_config(tmp_path / "slow.toml", make_raw(SLOW))
    out = tmp_path / "out"
    p = popen_capture("--config", str(cfg), "--out", str(out), "--no-progress")
    wait_for_rows(out / "slice.csv", 3, p)
    lines: list[str] = []
    seen = threading.Event()

    def drain() -> None:  # stderr read as it comes, so the second signal waits for the first's acknowledgement
        for line in p.stderr:  # type: ignore[union-attr]
            lines.append(line)
            if "received: stopping" in line:
                seen.set()

    reader = threading.Thread(target=drain, daemon=True)
    reader.start()
    p.send_signal(first)
    # pending signals are run in signal-number order, so two that arrive before the process runs either would
    # be seen as SIGINT first: the second is sent once the first is acknowledged
    assert seen.wait(30), "".join(lines)
    time.sleep(gap)
    p.send_signal(second)
    p.wait(timeout=30)
    reader.join(timeout=30)
    err = "".join(lines)
    assert p.returncode == code, err
    assert "Traceback" not in err and "KeyboardInterrupt" not in err, err
    assert f"interrupted by {signal.Signals(first).name}" in err and "--resume" in err
    n = rows(out / "slice.csv")
    fast = write_config(tmp_path / "fast.toml", make_raw())
    r = run_capture("--config", str(fast), "--out", str(out), "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    assert sorted(keys(read(out / "slice.csv"))) == planned(fast) and n >= 3


@pytest.mark.slow
def test_a_signal_during_the_final_dark_reading_is_an_interrupted_exit(tmp_path):
    raw = make_raw({"detector": {"dark_repeats": 1000}}, SLOW)  # the final dark takes ~1.3 s of wall time
    cfg = write_config(tmp_path / "slow.toml", raw)
    out = tmp_path / "out"
    p = popen_capture("--config", str(cfg), "--out", str(out), "--no-progress")
    wait_for_rows(out / "slice.csv", len(planned(cfg)), p, timeout=60)
    p.send_signal(signal.SIGTERM)
    _, err = p.communicate(timeout=30)
    assert p.returncode == 143, err
    assert "interrupted by SIGTERM" in err and "Traceback" not in err
    sidecar = json.loads((out / "capture.json").read_text())
    assert sidecar["status"] == "interrupted" and "dark_drift" not in sidecar
    r = run_capture("--config", str(write_config(tmp_path / "fast.toml", make_raw())), "--out", str(out), "--resume",
                    "--no-progress")
    assert r.returncode == 0, r.stderr
    sidecar = json.loads((out / "capture.json").read_text())
    assert sidecar["status"] == "complete" and len(sidecar["dark_drift"]) == 1
    assert sidecar["runs"][-1]["samples_new"] == 0


# --- a full disk, read-only outputs ------------------------------------------------------------------------------


def _file_size_limit(nbytes: int):
    import resource

    def pre() -> None:
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # writes beyond the limit then fail (EFBIG)
        resource.setrlimit(resource.RLIMIT_FSIZE, (nbytes, nbytes))
    return pre


@pytest.mark.slow
def test_a_full_disk_during_a_capture_is_one_line_and_the_capture_resumes(tmp_path):
    raw = make_raw({"detector": {"type": "spectrometer"}, "plan": {"theta_o_step_deg": 10.0},
                    "simulator": {"spectrometer": {"wl_min_nm": 400.0, "wl_max_nm": 700.0, "wl_step_nm": 20.0}}})
    cfg = write_config(tmp_path / "spec.toml", raw)
    ref = tmp_path / "ref"
    assert run_capture("--config", str(cfg), "--out", str(ref), "--no-progress").returncode == 0
    lines = (ref / "slice.csv").read_bytes().split(b"\n")
    limit = len(b"\n".join(lines[:3])) + int(3.5 * len(lines[3]))  # the header and three and a half rows
    assert limit > (ref / "capture.json").stat().st_size
    out = tmp_path / "out"
    r = subprocess.run([sys.executable, "-m", "acquisition.cli", "--config", str(cfg), "--out", str(out),
                        "--no-progress"], cwd=REPO, capture_output=True, text=True, timeout=120,
                       preexec_fn=_file_size_limit(limit))
    assert r.returncode == 1, r.stderr
    assert one_line(r.stderr) and "Logging error" not in r.stderr, r.stderr
    assert f"the disk is full (or a file size limit was reached): cannot write {out / 'slice.csv'}" in r.stderr
    assert "3 sample(s) are safely in" in r.stderr
    assert f"Free some space, then resume with: gonio-capture --config {cfg} --out {out} --resume" in r.stderr
    assert json.loads((out / "capture.json").read_text())["status"] == "failed"
    r = run_capture("--config", str(cfg), "--out", str(out), "--resume", "--no-progress")
    assert r.returncode == 0, r.stderr
    s = read(out / "slice.csv")  # the torn row was cut, none is missing or twice
    assert sorted(keys(s)) == planned(cfg) and s.channels == read(ref / "slice.csv").channels


def _unprivileged_capture(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([sys.executable, "-m", "acquisition.cli", *args, "--no-progress"], cwd=REPO,
                          capture_output=True, text=True, timeout=60, **unprivileged())


@pytest.mark.slow
def test_read_only_outputs_are_refused_before_anything_moves(tmp_path, capsys):
    cfg = write_config(tmp_path / "c.toml", make_raw())
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    r = _unprivileged_capture("--config", str(cfg), "--out", str(ro))
    assert r.returncode == 2 and f"--out {ro}: cannot create the lock file" in r.stderr, r.stderr
    assert "Traceback" not in r.stderr and "Resume with" not in r.stderr and "nothing was moved" in r.stderr
    assert list(ro.iterdir()) == []
    out, _ = partial_capture(tmp_path, capsys)
    snapshot = {p.name: p.read_bytes() for p in out.iterdir()}
    out.chmod(0o555)  # --resume in a read-only folder
    r = _unprivileged_capture("--config", str(cfg), "--out", str(out), "--resume")
    out.chmod(0o755)
    # a finished run removed its lock file: the read-only folder cannot have a new one
    assert r.returncode == 2 and f"--out {out}: cannot create the lock file capture.lock (Permission denied)" \
        in r.stderr
    assert "Traceback" not in r.stderr and "Resume with" not in r.stderr, r.stderr
    (out / "slice.csv").chmod(0o444)  # a read-only slice.csv
    r = _unprivileged_capture("--config", str(cfg), "--out", str(out), "--resume")
    assert r.returncode == 2 and f"--out {out}: slice.csv cannot be written (Permission denied)" in r.stderr
    assert "Traceback" not in r.stderr and "Resume with" not in r.stderr, r.stderr
    assert {p.name: p.read_bytes() for p in out.iterdir()} == snapshot  # no simulator started, nothing logged
    (out / "slice.csv").chmod(0o644)
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0


@pytest.mark.parametrize("signals", [1, 2])
def test_a_signal_while_parking_after_a_complete_capture_is_not_exit_0(tmp_path, capsys, monkeypatch, signals):
    """SIGTERM arriving while the arms park at the end (sent from inside the parking, in this process): the
    samples are all there, the exit status says 143; a second one aborts the parking, torque still goes off."""
    from acquisition.bench import Bench

    real_shutdown = Bench.shutdown

    def shutdown_with_signals(self, park=True):
        for _ in range(signals):
            os.kill(os.getpid(), signal.SIGTERM)
        return real_shutdown(self, park)

    monkeypatch.setattr(Bench, "shutdown", shutdown_with_signals)
    cfg = write_config(tmp_path / "c.toml", make_raw({"plan": {"theta_o_step_deg": 20.0}}))
    out = tmp_path / "out"
    assert main(["--config", str(cfg), "--out", str(out), "--no-progress"]) == 143
    err = capsys.readouterr().err
    assert "captured 7 new sample(s)" in err and "SIGTERM arrived while parking the arms" in err
    assert "Traceback" not in err
    log = (out / "capture.log").read_text()
    assert "motion released (torque off)" in log
    assert ("parking failed: parking aborted by a second SIGTERM" in log) == (signals == 2)
    assert ("arms parked at" in log) == (signals == 1)
    assert sorted(keys(read(out / "slice.csv"))) == planned(cfg)
