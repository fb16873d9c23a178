"""Benchmark: solids of revolution, slice -> full MERL table; prints seconds (median of repeats).

Run: .venv/bin/python benchmarks/bench_revolve.py [--repeats N]

Times ``revolve.revolve_table`` (reconstruct_revolve + merltable.tabulate at bin centres, 1,458,000 direction
pairs) on a one-incidence slice of the default plan (theta_i 30 deg, theta_o -80..80 every 2 deg, the blind
spot +-6 deg dropped) of the bench's blue plastic (Lambert + GGX, RGB), then its parts, a four-incidence
slice, the thesis's hemisphere map, and the O(n log n) merge of 10^6 points. Target: < 1 s per table.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from reconstruction.core import merlgrid, merltable
from reconstruction.core.geometry import inplane_to_dirs, sph_to_vec
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice
from reconstruction.methods import revolve as rv

BLUE = Material.from_dict({"name": "blue-plastic", "lobes": [
    {"type": "lambert", "albedo": [0.05, 0.10, 0.40]},
    {"type": "ggx", "alpha": 0.15, "specular": [0.9, 0.9, 0.9], "f0": 0.04}]})


def plan_slice(tis: list[float]) -> Slice:
    ti, to = (a.ravel() for a in np.meshgrid(np.asarray(tis, float), np.arange(-80.0, 80.5, 2.0), indexing="ij"))
    keep = np.abs(ti + to) >= 6.0
    ti, to = ti[keep], to[keep]
    return Slice(ti, to, BLUE.eval(*inplane_to_dirs(np.radians(ti), np.radians(to))), ["R", "G", "B"])


def timed(fn: Callable[[], Any], repeats: int) -> float:
    ts = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        ts.append(time.perf_counter() - t0)
    return statistics.median(ts)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    r = args.repeats
    load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
    one, four = plan_slice([30.0]), plan_slice([10.0, 30.0, 50.0, 70.0])
    merltable.tabulate(lambda wi, wo: np.zeros((wi.shape[0], 1)))  # warm tabulate's cached cell directions
    rv.revolve_table(one)  # warm-up
    t_table = timed(lambda: rv.revolve_table(one), r)
    t_build = timed(lambda: rv.reconstruct_revolve(one), r)
    rec = rv.reconstruct_revolve(one)
    # the bin-centre pairs merltable.tabulate evaluates, from the public cell_to_dirs
    cells = np.meshgrid(np.arange(merltable.SHAPE[1]), np.arange(merltable.SHAPE[2]), np.arange(merltable.SHAPE[3]),
                        indexing="ij")
    wi, wo = (a.reshape(-1, 3) for a in merlgrid.cell_to_dirs(*cells))
    t_eval = timed(lambda: rec.eval(wi, wo), r)
    t_four = timed(lambda: rv.revolve_table(four), r)
    t_hemi = timed(lambda: rv.thesis_hemisphere(one), r)
    rng = np.random.default_rng(0)
    n = 1_000_000
    pts = sph_to_vec(np.arccos(rng.uniform(0, 1, n)), rng.uniform(-np.pi, np.pi, n)) * rng.uniform(0, 1, n)[:, None]
    t_merge = timed(lambda: rv.merge_solids(pts), r)
    print(f"{os.cpu_count()} CPUs, load average {load} (1 / 5 / 15 min) before the runs")
    print(f"revolve, one slice -> full MERL table: {t_table * 1e3:7.1f} ms  (target < 1000 ms; median of {r})")
    print(f"  reconstruct_revolve:                 {t_build * 1e3:7.1f} ms")
    print(f"  eval of {wi.shape[0]:,} pairs:             {t_eval * 1e3:7.1f} ms")
    print(f"four incidences -> full MERL table:    {t_four * 1e3:7.1f} ms")
    print(f"thesis hemisphere map (1 deg grid):    {t_hemi * 1e3:7.1f} ms")
    print(f"merge of 10^6 points (snap + sort):    {t_merge * 1e3:7.1f} ms")


if __name__ == "__main__":
    main()
