"""Rerun the hostile campaign of issue 11 and print its counts: cases tried, handled cleanly, tracebacks, data lost.

    .venv/bin/python scripts/hostile_campaign.py            # everything, a few minutes on 2 cores
    .venv/bin/python scripts/hostile_campaign.py --quick    # fewer kill / concurrency trials

Parts (the corpora are those of the test suite, tests/hostile.py):

* hostile inputs and outputs of ``gonio-reconstruct`` and hostile bench / scene files of ``gonio-capture --check``
  (subprocesses): clean = exit 0 or 2 (1 only for an I/O fault), one line, no traceback, no output half-written;
* silent wrong answers (issue 49, tests/hostile_silent.py): tampered capture folders resumed, ``--check`` of a PM100
  bench without a VISA library, reconstructions the samples cannot support: refused naming why (the files left as
  they were) or done with the warning they need;
* mutations of every shipped config: refused by ``--check`` naming the file and the key, or captured to
  completion on the simulator;
* two captures started together on one ``--out``: one completes, the other refuses at once;
* ``kill -9`` of a capture at a random moment, then ``--resume``: the slice ends with exactly the planned samples;
* fault storms: every fault kind at 0.01 / 0.05 / 0.2, resumed until complete;
* the live view under abuse (tests/hostile_live.py) and ``gonio-reconstruct --method auto`` on 300,000 rows under
  a 1.5 GB and a 400 MB address-space limit (issue 49).

"Data lost" counts samples lost, changed or taken twice, and outputs left half-written under their real names.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import os
import shutil
import signal
import subprocess
import sys
import time
import traceback
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests import hostile, hostile_silent  # noqa: E402
from tests.helpers import planned  # noqa: E402
from tests.test_acq_support import keys, make_raw, read, write_config  # noqa: E402
from tests.test_fault_storms import MAX_RUNS, STORMS, storm_raw  # noqa: E402


class Tally:
    def __init__(self, name: str) -> None:
        self.name = name
        self.tried = self.clean = self.tracebacks = self.lost = 0
        self.notes: list[str] = []

    def add(self, clean: bool, traceback_seen: bool = False, lost: int = 0, note: str = "") -> None:
        self.tried += 1
        self.clean += bool(clean)
        self.tracebacks += bool(traceback_seen)
        self.lost += lost
        if not clean and note:
            self.notes.append(note)


def _main_quietly(argv: list[str]) -> tuple[int, str]:
    """``gonio-capture ARGV`` in this process; (exit status, stderr); an exception counts as a traceback."""
    from acquisition.cli import main

    err = io.StringIO()
    try:
        with contextlib.redirect_stderr(err), contextlib.redirect_stdout(io.StringIO()):
            code = main(argv)
    except BaseException:  # noqa: BLE001 - what the campaign looks for
        return -1, err.getvalue() + "Traceback (most recent call last):\n" + traceback.format_exc()
    return code, err.getvalue()


def corpus(name: str, cases: list[hostile.Case]) -> Tally:
    t = Tally(name)
    for o in hostile.run_all(cases):
        t.add(o.clean, o.traceback, int(o.lost), f"{o.case.name}: {'; '.join(o.problems)}")
    return t


def mutations(work: Path) -> Tally:
    t = Tally("config mutations (--check, then a capture)")
    for name in hostile.CONFIGS:
        for k, m in enumerate(hostile.config_mutations(name, 42)):
            d = work / f"{name}-{k}"
            d.mkdir(parents=True)
            cfg = hostile.mutated_config(name, m, d)
            code, err = _main_quietly(["--config", str(cfg), "--check"])
            tb = "Traceback" in err
            if code == 2:
                named = m.key if m.key is not None else m.section[-1]
                ok = err.startswith(f"gonio-capture: {cfg}") and named in err and not tb
            elif code == 0:
                cap = hostile.capturable(name, m, cfg, d)
                code, err = _main_quietly(["--config", str(cap), "--out", str(d / "out"), "--no-progress"])
                tb = tb or "Traceback" in err
                ok = code == 0 and not tb
            else:
                ok = False
            t.add(ok, tb, 0, f"{name}: {m.name}: exit {code}: {err.strip()[-200:]}")
    return t


def _capture(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "acquisition.cli", *args, "--no-progress"], cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def _rows(path: Path) -> int:
    try:
        return sum(1 for line in path.read_text().splitlines() if line[:1].isdigit())
    except (FileNotFoundError, UnicodeDecodeError):
        return 0


def concurrency(work: Path, trials: int) -> Tally:
    work.mkdir(parents=True, exist_ok=True)
    t = Tally("two captures on one --out")
    cfg = write_config(work / "slow.toml", make_raw({"simulator": {"time_scale": 8.0}}))
    for k in range(trials):
        out = work / f"two-{k}"
        a, b = _capture("--config", str(cfg), "--out", str(out)), _capture("--config", str(cfg), "--out", str(out))
        (_, ea), (_, eb) = a.communicate(timeout=120), b.communicate(timeout=120)
        codes = sorted([a.returncode, b.returncode])
        tb = "Traceback" in ea + eb
        try:
            s = read(out / "slice.csv")
            lost = len(set(planned(cfg)) ^ set(keys(s)))
        except Exception:  # noqa: BLE001 - an unreadable slice is data lost
            lost = len(planned(cfg))
        t.add(codes == [0, 2] and not tb and lost == 0, tb, lost, f"trial {k}: exit {codes}, lost {lost}")
    return t


def kills(work: Path, trials: int) -> Tally:
    work.mkdir(parents=True, exist_ok=True)
    import numpy as np

    t = Tally("kill -9 at a random moment, then --resume")
    slow = write_config(work / "kill-slow.toml", make_raw({"simulator": {"time_scale": 8.0}}))
    fast = write_config(work / "kill-fast.toml", make_raw())
    rng = np.random.default_rng(11)
    for k in range(trials):
        out = work / f"kill-{k}"
        p = _capture("--config", str(slow), "--out", str(out))
        time.sleep(float(rng.uniform(0.2, 1.5)))
        if p.poll() is None:
            os.kill(p.pid, signal.SIGKILL)
        p.communicate(timeout=60)
        before = {}
        if (out / "slice.csv").exists():
            try:
                s0 = read(out / "slice.csv")
                before = dict(zip(keys(s0), s0.values[:, 0].tolist(), strict=True))
            except Exception:  # noqa: BLE001
                before = {}
        code, err = _main_quietly(["--config", str(fast), "--out", str(out), "--resume", "--no-progress"])
        try:
            s = read(out / "slice.csv")
            now = dict(zip(keys(s), s.values[:, 0].tolist(), strict=True))
            lost = len(set(planned(fast)) ^ set(now)) + sum(now.get(key) != v for key, v in before.items())
        except Exception:  # noqa: BLE001
            lost = len(planned(fast))
        tb = "Traceback" in err
        t.add(code == 0 and lost == 0 and not tb, tb, lost, f"trial {k}: exit {code}, lost {lost}")
    return t


def storms(work: Path) -> Tally:
    t = Tally("fault storms (each kind at 0.01 / 0.05 / 0.2)")
    for kind, rate, motion, faults, over, completes in STORMS:
        raw = storm_raw(kind, rate, motion, faults, over)
        d = work / f"storm-{kind}-{rate}"
        d.mkdir(parents=True)
        cfg = write_config(d / "storm.toml", raw)
        out = d / "out"
        seen: dict = {}
        lost = 0
        tb = False
        codes = []
        for run in range(MAX_RUNS if completes else 3):
            code, err = _main_quietly(["--config", str(cfg), "--out", str(out), "--no-progress"]
                                      + (["--resume"] if run else []))
            codes.append(code)
            tb = tb or "Traceback" in err
            if (out / "slice.csv").exists():
                s = read(out / "slice.csv")
                now = dict(zip(keys(s), s.values[:, 0].tolist(), strict=True))
                lost += sum(k not in now or now[k] != v for k, v in seen.items())
                seen = now
            if code != 1:
                break
        done = codes[-1] == 0 and sorted(seen) == planned(cfg)
        safe = all(c in (0, 1) for c in codes)
        ok = safe and not tb and lost == 0 and (done or not completes)
        t.add(ok, tb, lost, f"{kind} {rate}: runs {codes}")
        if not completes:
            t.notes.append(f"{kind} {rate}: {len(codes)} runs stopped safely (exit 1, data intact); completion is "
                           "not expected at this rate")
    return t


# --- issue 49 (items 7-10): the live view under abuse, large inputs under a memory limit ------------------------


def live_view(work: Path) -> Tally:
    """The live view's abuse (tests/hostile_live.py): a header flood, 1000 half-open connections, foreign Host
    names on 127.0.0.1 and 0.0.0.0, links out of the capture folder."""
    from tests import hostile_live

    t = Tally("live view under abuse (flood, half-open, Host, links)")
    for case in hostile_live.LIVE_CASES:
        try:
            out = case(work)
            t.add(out.clean, note=f"{out.name}: {out.note}")
        except Exception:  # noqa: BLE001 - a case that breaks is counted, not fatal
            t.add(False, True, note=traceback.format_exc(limit=3))
    return t


def large_inputs(work: Path) -> Tally:
    """gonio-reconstruct --method auto on 300,000 rows under a 1.5 GB address-space limit (completes), and under
    400 MB (one line, exit 1, nothing written)."""
    from reconstruction.formats.slicefile import write_slice
    from tests.test_memory import LIMIT_BYTES, _run_limited, big_slice

    t = Tally("auto on 300,000 rows under 1.5 GB / 400 MB")
    work.mkdir(parents=True, exist_ok=True)
    big = work / "big.csv"
    write_slice(big, big_slice(300_000))
    for limit, want in ((LIMIT_BYTES, 0), (400 * 1024 * 1024, 1)):
        out = work / f"m-{limit}.binary"
        code, err, _ = _run_limited([str(big), "--method", "auto", "--out", str(out)], limit)
        one_line = want == 0 or (err.count("\n") == 1 and "out of memory" in err and not out.exists())
        t.add(code == want and one_line and "Traceback" not in err, "Traceback" in err,
              note=f"limit {limit >> 20} MB: exit {code}: {err.strip()[-300:]}")
    return t


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="fewer kill / concurrency trials")
    ap.add_argument("--keep", action="store_true", help="keep the work folder")
    args = ap.parse_args(argv)
    work = hostile.new_workdir()
    t0 = time.perf_counter()
    trials = 3 if args.quick else 10
    try:
        parts = [
            corpus("hostile inputs/outputs of gonio-reconstruct", hostile.reconstruct_cases(work / "reconstruct")),
            corpus("hostile configs/scenes of gonio-capture --check", hostile.capture_check_cases(work / "capture")),
            corpus("silent wrong answers: tampered resumes, unsupported tables (issue 49)",
                   hostile_silent.capture_cases(work / "silent-capture")
                   + hostile_silent.reconstruct_cases(work / "silent-reconstruct")),
            mutations(work / "mutations"),
            concurrency(work / "concurrency", trials),
            kills(work / "kills", trials),
            storms(work / "storms"),
            live_view(work / "live"),
            large_inputs(work / "large"),
        ]
    finally:
        if not args.keep:
            for p in work.rglob("*"):
                if not p.is_symlink():
                    p.chmod(0o755 if p.is_dir() else 0o644)
            shutil.rmtree(work, ignore_errors=True)
    width = max(len(p.name) for p in parts)
    print(f"{'part':{width}}  {'tried':>6} {'clean':>6} {'tracebacks':>10} {'data lost':>9}")
    for p in parts:
        print(f"{p.name:{width}}  {p.tried:6d} {p.clean:6d} {p.tracebacks:10d} {p.lost:9d}")
    total = Tally("total")
    for p in parts:
        total.tried += p.tried
        total.clean += p.clean
        total.tracebacks += p.tracebacks
        total.lost += p.lost
    print(f"{'total':{width}}  {total.tried:6d} {total.clean:6d} {total.tracebacks:10d} {total.lost:9d}")
    print(f"({time.perf_counter() - t0:.0f} s{'; work folder ' + str(work) if args.keep else ''})")
    for p in parts:
        for note in p.notes:
            print(f"  {p.name}: {note}")
    return 0 if total.clean == total.tried and total.tracebacks == 0 and total.lost == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
