"""Capture software overhead per sample, with the simulator in fast mode (time_scale = 0).

In fast mode simulated time costs no wall time, so the wall time of a capture is all software: the acquisition
code, the real dynamixel_sdk / pyserial, the pseudo-terminals and the simulator's own processing. The overhead
per sample is the slope of wall time against the number of samples (two plan sizes), which excludes the fixed
costs (simulator start, set-up, dark and white-reference readings), printed separately.

    .venv/bin/python benchmarks/bench_capture.py [--repeats 3]
"""

from __future__ import annotations

import argparse
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

from acquisition import Bench, Plan  # noqa: E402


def config(tmp: Path, motion: str) -> Path:
    raw = tomllib.loads((REPO / "configs" / "simulated.toml").read_text())
    raw["bench"]["motion"] = motion
    raw.setdefault("simulator", {})["time_scale"] = 0.0
    p = tmp / f"{motion}.toml"
    p.write_text(tomli_w.dumps(raw))
    return p


def timed_capture(bench: Bench, plan: Plan, out: Path) -> tuple[float, int, float]:
    t0 = time.perf_counter()
    r = bench.capture(plan, out=out, progress=False)
    wall = time.perf_counter() - t0
    r.raise_for_status()
    return wall, r.samples_new, r.bench_time_s


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--repeats", type=int, default=3, help="captures per plan size (median taken)")
    args = ap.parse_args()
    small = Plan.grid([30.0], -80.0, 80.0, 4.0)                    # 38 samples
    large = Plan.grid([20.0, 40.0, 60.0], -80.0, 80.0, 1.0)         # ~450 samples
    print(f"simulator in fast mode (time_scale = 0); plans of {len(small.requested_points())} and "
          f"{len(large.requested_points())} points, 4 repeats per point; median of {args.repeats}")
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for motion in ("dynamixel", "serial"):
            cfg = config(tmp, motion)
            t_open = time.perf_counter()
            bench = Bench.from_config(cfg).open()
            t_open = time.perf_counter() - t_open
            try:
                res = {}
                for name, plan in (("small", small), ("large", large)):
                    runs = [timed_capture(bench, plan, tmp / f"{motion}-{name}-{k}") for k in range(args.repeats)]
                    res[name] = (statistics.median(r[0] for r in runs), runs[0][1], runs[0][2])
            finally:
                bench.shutdown()
                bench.close()
            (w1, n1, _), (w2, n2, s2) = res["small"], res["large"]
            per = (w2 - w1) / (n2 - n1)
            fixed = w1 - per * n1
            print(f"{motion:9s} bench: {per * 1e3:6.2f} ms software overhead per sample "
                  f"({n2} samples in {w2:.2f} s wall for {s2:.1f} s of simulated capture time, "
                  f"{s2 / w2:.0f}x faster than real time); fixed cost per capture {fixed * 1e3:.0f} ms "
                  f"(dark, white reference, final dark, park); opening the bench {t_open * 1e3:.0f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main())
