"""Benchmark: write and read a full MERL table (34,992,012 bytes); prints seconds and MB/s.

Run: .venv/bin/python benchmarks/bench_merl.py [--repeats N]
"""

from __future__ import annotations

import argparse
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

from reconstruction.core import merltable
from reconstruction.formats import merl


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    f = np.random.default_rng(0).uniform(0, 10, merltable.SHAPE)
    f[:, :, 85:, :] = np.nan
    mb = merl.FILE_SIZE / 1e6
    tw, tr = [], []
    with tempfile.TemporaryDirectory() as d:
        p = Path(d) / "bench.binary"
        for _ in range(args.repeats):
            t0 = time.perf_counter()
            merl.write(p, f)
            t1 = time.perf_counter()
            merl.read(p)
            t2 = time.perf_counter()
            tw.append(t1 - t0)
            tr.append(t2 - t1)
    w, r = statistics.median(tw), statistics.median(tr)
    print(f"MERL write: {w * 1e3:7.1f} ms  {mb / w:7.0f} MB/s   (median of {args.repeats}, includes fsync)")
    print(f"MERL read:  {r * 1e3:7.1f} ms  {mb / r:7.0f} MB/s")
    print(f"write + read: {(w + r) * 1e3:.1f} ms (target < 200 ms)")


if __name__ == "__main__":
    main()
