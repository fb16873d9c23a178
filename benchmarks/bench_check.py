"""How long ``gonio-capture --check`` takes on the largest bench file a plan can be.

An explicit list of MAX_PLAN_POINTS points with 4 repeats on the simulated bench (configs/simulated.toml), checked
in a child process as a lab user runs it (interpreter start and imports included); prints each of five runs and
the best. The README's "returns in about a second" is this figure. Usage::

    .venv/bin/python benchmarks/bench_check.py
"""

from __future__ import annotations

import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomli_w
import tomllib

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from acquisition.plans.planconfig import MAX_PLAN_POINTS  # noqa: E402


def main() -> int:
    raw = tomllib.loads((ROOT / "configs" / "simulated.toml").read_text(encoding="utf-8"))
    raw.pop("plan", None)
    ti = np.repeat(np.arange(0.0, 85.0, 0.5), 200)[:MAX_PLAN_POINTS]
    to = np.tile(np.linspace(-85.0, 85.0, 200), 200)[:MAX_PLAN_POINTS]
    points = ",".join(f"[{a:g},{b:.3f}]" for a, b in zip(ti, to, strict=True))
    with tempfile.TemporaryDirectory() as d:
        cfg = Path(d) / "big.toml"
        cfg.write_text(tomli_w.dumps(raw) + f"\n[plan]\nrepeats = 4\npoints = [{points}]\n", encoding="utf-8")
        print(f"bench file {cfg.stat().st_size / 1024:.0f} KB, {MAX_PLAN_POINTS} points; {os.cpu_count()} CPUs, load "
              f"average {os.getloadavg()[0]:.2f}")
        walls = []
        for k in range(5):
            t0 = time.perf_counter()
            r = subprocess.run([sys.executable, "-m", "acquisition.cli", "--config", str(cfg), "--check"],
                               cwd=ROOT, capture_output=True, text=True)
            walls.append(time.perf_counter() - t0)
            if r.returncode != 0:
                print(r.stderr.strip())
                return 1
            print(f"  run {k + 1}: {walls[-1]:.3f} s")
    print(f"gonio-capture --check of the largest plan: best {min(walls):.3f} s, median {np.median(walls):.3f} s")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
