"""Capture software overhead per sample and per capture, with the simulator in fast mode (time_scale = 0).

In fast mode simulated time costs no wall time, so the wall time of a capture is all software: the acquisition
code, the real dynamixel_sdk / pyserial, the pseudo-terminals and the simulator's own processing. Every figure is
measured directly, from the wall clock around ``Bench.capture`` and the capture's own record (each slice row
carries the unix time it was written):

* per sample = (time of the last row - time of the first row) / (samples - 1): one pass of the measuring loop
  (move command and in-position polling, settle, the detector readings, calibration, appending the row with
  fsync). Plan ordering happens before the first sample and is not in it.
* fixed cost per capture = wall time of a one-point capture - one sample: plan validation, output folder and
  log, dark and white-reference readings, final dark reading, park, run record.
* plan ordering: ``order_points`` on the large plan's points, timed on its own (its memory of recent orders
  emptied first). It is not fixed: it grows with the plan, and a capture runs it once before its first sample (the
  estimate it logs orders the points, and the capture reuses that order).
* the large capture as a whole: samples x per sample + the time before the first row (set-up, plan ordering;
  measured as the time to the first row minus one sample) + the time after the last row (final dark reading,
  park, run record).
* opening the bench (simulator start, connection, device initialisation) happens once per bench, not per
  capture.

    .venv/bin/python benchmarks/bench_capture.py [--repeats 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import tomli_w

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from acquisition import Bench, Plan, order_points  # noqa: E402
from reconstruction.formats.slicefile import read_slice  # noqa: E402


def _forget_orders() -> None:
    """Empty order_points' memory of recent orders (a capture reuses the order its estimate computed)."""
    try:
        from acquisition.plans.ordering import _ORDERED
    except ImportError:  # an older version without it
        return
    _ORDERED.clear()


def config(tmp: Path, motion: str) -> Path:
    raw = tomllib.loads((REPO / "configs" / "simulated.toml").read_text())
    raw["bench"]["motion"] = motion
    raw.setdefault("simulator", {})["time_scale"] = 0.0
    p = tmp / f"{motion}.toml"
    p.write_text(tomli_w.dumps(raw))
    return p


def timed_capture(bench: Bench, plan: Plan, out: Path) -> dict[str, float]:
    """Capture ``plan``; wall time, samples, bench (simulated) time and the phases read from the slice rows."""
    _forget_orders()  # every capture as the first: it orders its points once
    t0 = time.time()
    r = bench.capture(plan, out=out, progress=False)
    t1 = time.time()
    r.raise_for_status()
    rows = sorted(read_slice(r.slice_path).unix_time_s)
    n = len(rows)
    wall = t1 - t0
    per = (rows[-1] - rows[0]) / (n - 1) if n > 1 else float("nan")
    return {"wall": wall, "n": n, "bench": r.bench_time_s, "per": per,
            "before": rows[0] - t0 - per, "after": t1 - rows[-1], "fixed": wall - n * per}


def ms(x: float) -> str:
    return f"{x * 1e3:.1f} ms"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="captures per plan (median taken)")
    args = ap.parse_args()
    one = Plan.grid([30.0], 10.0, 10.0, 1.0)                        # one point
    large = Plan.grid([20.0, 40.0, 60.0], -80.0, 80.0, 1.0)         # ~450 measurable points
    load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"simulator in fast mode (time_scale = 0); {os.cpu_count()} CPUs, load average {load} (1 / 5 / 15 min); "
          f"median of {args.repeats} captures; {large.repeats} detector readings per point")
    summary = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for motion in ("dynamixel", "serial"):
            cfg = config(tmp, motion)
            t_open = time.perf_counter()
            bench = Bench.from_config(cfg).open()
            t_open = time.perf_counter() - t_open
            try:
                pts = large.validate(bench.geometry).measurable
                t_order = []
                for _ in range(args.repeats):
                    _forget_orders()  # the ordering itself, not its reuse
                    t = time.perf_counter()
                    order_points(pts, bench.geometry, start=bench.positions())
                    t_order.append(time.perf_counter() - t)
                big = [timed_capture(bench, large, tmp / f"{motion}-large-{k}") for k in range(args.repeats)]
                small = [timed_capture(bench, one, tmp / f"{motion}-one-{k}") for k in range(args.repeats)]
            finally:
                bench.shutdown()
                bench.close()

            def med(runs: list[dict[str, float]], key: str) -> float:
                return statistics.median(r[key] for r in runs)

            per, before, after = (med(big, k) for k in ("per", "before", "after"))
            wall, bench_s, n = med(big, "wall"), med(big, "bench"), int(big[0]["n"])
            order = statistics.median(t_order)
            fixed = med(small, "wall") - per
            print(f"{motion} bench:")
            print(f"  per sample:             {ms(per):>9}  (wall time from the first to the last slice row / "
                  f"{n - 1}: move, settle, {large.repeats} readings, calibration, row append)")
            print(f"  fixed cost per capture: {ms(fixed):>9}  (one-point capture wall time {ms(med(small, 'wall'))} "
                  f"- one sample: validation, output folder and log, dark and white-reference readings, final dark, "
                  f"park, run record)")
            print(f"  plan ordering:          {ms(order):>9}  (order_points on {len(pts)} points, timed alone; "
                  f"grows with the plan; a capture orders its points before the first sample)")
            print(f"  whole large capture:    {wall * 1e3:6.0f} ms  = {n} x per sample {n * per:.2f} s + before the "
                  f"first sample {ms(before)} (set-up, plan ordering) + after the last {ms(after)} (final dark, park, "
                  f"run record); {bench_s:.1f} s of simulated bench time, {bench_s / wall:.0f}x faster than real time")
            print(f"  opening the bench:      {ms(t_open):>9}  (simulator start, connection, device set-up; once "
                  f"per bench, not per capture)")
            summary.append(f"{ms(per)} per sample, {ms(fixed)} per capture, plan ordering {ms(order)} for "
                           f"{len(pts)} points ({motion} bench)")
    print("capture software overhead, simulator in fast mode: " + "; ".join(summary))
    return 0


if __name__ == "__main__":
    sys.exit(main())
