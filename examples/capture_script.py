"""A lab-bench script with the acquisition Python API: check a plan, capture it, look at the result.

    python examples/capture_script.py [CONFIG] [OUT_DIR]

Defaults: configs/simulated.toml (the simulated bench: gonio-sim runs as a child process) and out/example.
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from acquisition import Bench
from reconstruction.formats.slicefile import read_slice


def main() -> int:
    config = sys.argv[1] if len(sys.argv) > 1 else "configs/simulated.toml"
    out = Path(sys.argv[2] if len(sys.argv) > 2 else "out/example")

    bench = Bench.from_config(config)             # validates the whole file; nothing moves yet
    plan = bench.plan()                           # the config's [plan] ...
    # ... or any plan built in code (from acquisition import Plan):
    #     plan = Plan.grid(theta_i, theta_o_min, theta_o_max, step, repeats=...)
    check = bench.check(plan)
    print(check.describe())
    est = plan.estimate(bench.geometry, bench.cfg.detector.integration_time_s, cfg=bench.cfg)  # the whole capture
    print(f"estimated bench time {est['total_s']:.1f} s, of which motion {est['motion_s']:.1f} s (naive order "
          f"{est['naive_motion_s']:.1f} s)")

    with bench:                                   # opens the ports (starts the simulator if simulated)
        dark = bench.dark(16)
        print(f"dark level {dark.mean[0]:.1f} counts")
        bench.move(30.0, 30.0)                    # both arms at once; waits until in position
        bench.settle()
        spec = bench.read(4)                      # auto-ranged (a saturated reading is read again, less sensitive)
        print(f"specular reading {spec.mean[0]:.1f} counts at the reference setting ({spec.saturated} of "
              f"{spec.n} repeats saturated)")
        result = bench.capture(plan, out=out, resume=True, progress=False)   # resumable: run it again
    print(result.message)
    if not result.ok:
        return result.exit_code

    s = read_slice(out / "slice.csv")
    k = int(np.argmax(s.values[:, 0]))
    print(f"{len(s)} samples; peak f_r = {s.values[k, 0]:.3f} 1/sr at theta_i = {s.theta_i_deg[k]:g}, "
          f"theta_o = {s.theta_o_deg[k]:g}; simulated capture time {result.bench_time_s:.1f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
