"""Benchmark: a full MERL table from simulated slices, per method; prints seconds and the error vs ground truth.

Time = reconstruction + tabulation at bin centres (what `gonio-reconstruct` does before writing: revolve with
pipeline's reciprocal=True, twice the eval time of benchmarks/bench_revolve.py's table), median of
``--repeats`` runs, for one slice (theta_i = 30 deg, theta_o -80..80 deg every 2 deg, blind spot +-4 deg) and for
six incidences. The targets (2-core development machine) are for a full table from one slice: revolve,
bivariate and microfacet < 1 s, fit < 3 s; auto (cross-validation of every method, then the chosen method's
table) < 10 s; only the one-slice rows are compared with them (ok / SLOW), the six-slice rows are information.
The load average is printed: other jobs on the machine slow every figure down.
Error = relative RMSE of f cos(theta_i) cos(theta_o) over the table (reconstruction.core.metrics.relative_rmse_cos).

Run: .venv/bin/python benchmarks/bench_reconstruct.py [--repeats N] [--material configs/simulated.toml]
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from pathlib import Path

import numpy as np

from reconstruction import pipeline
from reconstruction.core import merltable
from reconstruction.core.metrics import relative_rmse_cos
from reconstruction.core.models import Material
from reconstruction.synthetic import synthetic_slice

REPO = Path(__file__).resolve().parents[1]
TARGETS = {"fit": 3.0, "microfacet": 1.0, "bivariate": 1.0, "revolve": 1.0, "auto": 10.0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--material", default=str(REPO / "configs" / "simulated.toml"))
    args = ap.parse_args()
    mat = Material.from_toml(args.material)
    truth = merltable.tabulate(mat.eval)
    methods = ["fit", "microfacet", "bivariate", "revolve", "auto"]
    load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"material {mat.name} ({args.material}); median of {args.repeats} repeats; {os.cpu_count()} CPUs, "
          f"load average {load} (1 / 5 / 15 min)")
    print(f"{'method':<10} {'slices':<22} {'reconstruct':>12} {'tabulate':>9} {'total':>8} {'target':>12} "
          f"{'error':>8}")
    totals: dict[int, dict[str, float]] = {}
    for incidences in ((30.0,), (0.0, 15.0, 30.0, 45.0, 60.0, 75.0)):
        s = synthetic_slice(mat, incidences)
        s.std = 0.005 * np.abs(s.values)  # a plausible uncertainty, without adding noise
        label = f"{len(incidences)} x {len(s) // len(incidences)} samples"
        for m in methods:
            tr, tt = [], []
            table = None
            for _ in range(args.repeats):
                t0 = time.perf_counter()
                rec, _ = pipeline.reconstruct(s, m)
                t1 = time.perf_counter()
                table = pipeline.tabulate(rec)
                t2 = time.perf_counter()
                tr.append(t1 - t0)
                tt.append(t2 - t1)
            r, t = statistics.median(tr), statistics.median(tt)
            totals.setdefault(len(incidences), {})[m] = r + t
            if len(incidences) == 1:  # the targets are for one slice
                target = f"< {TARGETS[m]:.0f} s {'ok' if r + t < TARGETS[m] else 'SLOW':<4}"
            else:
                target = "(none)"
            err = relative_rmse_cos(table, truth)
            print(f"{m:<10} {label:<22} {r:>11.3f}s {t:>8.3f}s {r + t:>7.3f}s {target:>12} {err:>8.4f}")
    one, six = totals[1], totals[6]
    print("full table from one slice: " + ", ".join(f"{m} {one[m]:.2f} s (< {TARGETS[m]:g} s)" for m in methods)
          + "; from six slices (no target): " + ", ".join(f"{m} {six[m]:.2f} s" for m in methods))


if __name__ == "__main__":
    main()
