"""Whether grbl-sim stalls (a fixture fault of grbl-sim alone: its main loop and interrupts ran on two threads
unsynchronised; the project's shim, firmware/grbl/sim/gonio_shim.c, runs them on one): back-and-forth
moves of both arms (``$110``/``$111`` 36000, ``$120``/``$121`` 4000, 10 steps/unit, +-80 units) with a ``?``
status poll at ``--hz``, for ``--seconds`` or until the harness's relay sees a stall (a moving state at one
``MPos`` for 3 s). ``--burners N`` runs N busy-looping processes beside it (a loaded CI machine); ``--runs`` repeats
on fresh grbl-sims. After a stall it sends a soft reset, ``$X`` and a move home, and prints what GRBL then
reports (whether the same grbl-sim moves again).

    .venv/bin/python benchmarks/bench_grbl_stall.py --hz 100 --seconds 180 --burners 1 --runs 2

Prints one line per run (moves, polls, seconds to the stall or none) and the polls per stall over all runs.
"""

from __future__ import annotations

import argparse
import multiprocessing
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from tests import grbl_harness as gh  # noqa: E402

# our build's defaults home and limit; this bench has no switches
SETTINGS = ("$20=0", "$22=0", "$100=10", "$101=10", "$110=36000", "$111=36000", "$120=4000", "$121=4000", "$X")


def _burn() -> None:
    while True:
        pass


def one_run(exe: Path, hz: float, seconds: float, workdir: Path) -> dict[str, float | int | bool]:
    """One grbl-sim driven until a stall or ``seconds``: moves made, polls sent, seconds, stalled, recovered."""
    sim = gh.GrblSim(exe, workdir)
    try:
        sim.wait_ready()
        for line in SETTINGS:
            sim.send_line(line)
        ser = sim._ser()
        target, moves, polls, buf, state = 80, 0, 0, b"", ""
        ser.write(f"G90 G0 X{target} Y{-target}\n".encode())
        t0 = time.monotonic()
        while time.monotonic() - t0 < seconds and sim.stall is None:
            ser.write(b"?")
            polls += 1
            time.sleep(1.0 / hz)
            buf += ser.read(ser.in_waiting or 1)
            for m in gh.STATUS_REPORT.finditer(buf):
                state = m.group(1).decode()
            buf = buf[buf.rfind(b">") + 1:]
            if state == "Idle":
                target, moves, state = -target, moves + 1, "sent"
                ser.write(f"G90 G0 X{target} Y{-target}\n".encode())
        elapsed = time.monotonic() - t0
        stalled = sim.stall is not None
        recovered = False
        if stalled:  # the replies still queued drain first (grbl-sim sends at the baud rate), then reset
            quiet_until, deadline = time.monotonic() + 0.5, time.monotonic() + 20
            while time.monotonic() < min(quiet_until, deadline):
                if ser.read(ser.in_waiting or 1):
                    quiet_until = time.monotonic() + 0.5
            ser.write(b"\x18")
            time.sleep(1.0)
            ser.write(b"$X\n")
            time.sleep(0.5)
            ser.write(b"G90 G0 X0 Y0\n")
            time.sleep(3.0)
            ser.reset_input_buffer()
            ser.write(b"?")
            seen, t_end = b"", time.monotonic() + 1.0
            while time.monotonic() < t_end:
                seen += ser.read(ser.in_waiting or 1)
            recovered = b"<Idle|MPos:0.000,0.000" in seen
            print(f"  after the reset, $X and G0 X0 Y0: {seen.decode(errors='replace').strip()!r}")
        return {"moves": moves, "polls": polls, "seconds": elapsed, "stalled": stalled, "recovered": recovered}
    finally:
        sim.close()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--hz", type=float, default=100.0, help="status polls per second (default 100)")
    ap.add_argument("--seconds", type=float, default=180.0, help="longest run (default 180)")
    ap.add_argument("--runs", type=int, default=2, help="runs on fresh grbl-sims (default 2)")
    ap.add_argument("--burners", type=int, default=1, help="busy processes beside it (default 1)")
    a = ap.parse_args(argv)
    missing = gh.missing()
    if missing:
        print(f"bench_grbl_stall: {missing}", file=sys.stderr)
        return 2
    burners = [multiprocessing.Process(target=_burn, daemon=True) for _ in range(a.burners)]
    for p in burners:
        p.start()
    polls = stalls = 0
    try:
        with tempfile.TemporaryDirectory() as tmp:
            exe = gh.build(Path(tmp) / "build")
            for k in range(a.runs):
                r = one_run(exe, a.hz, a.seconds, Path(tmp) / f"run{k}")
                polls += int(r["polls"])
                stalls += bool(r["stalled"])
                what = (f"stalled after {r['seconds']:.1f} s; reset + $X moved again: {r['recovered']}"
                        if r["stalled"] else f"no stall in {r['seconds']:.0f} s")
                print(f"run {k + 1}: {a.hz:g} Hz, {a.burners} burner(s): {r['moves']} moves, {r['polls']} polls, "
                      f"{what}")
    finally:
        for p in burners:
            p.terminate()
    print(f"{stalls} stall(s) in {polls} polls" + (f": one per {polls / stalls:.0f} polls" if stalls else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
