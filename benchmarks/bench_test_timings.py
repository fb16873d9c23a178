"""The times that unit tests used to bound by the wall clock, measured here instead (unit tests assert behaviour).

Each case is the one of the test named beside it, timed with the wall clock and the process's CPU time (best of
``--repeats``; a loaded machine shows in the wall time only); the bounds the tests held (issue 11's < 20 s for a
100 MB table, "at once" for a refused plan) are printed beside the figures:

* fit of a GGX alpha 0.005 lobe read through a 1e-3 sr cone, 4 incidences (tests/test_fit_instrument.py; the first
  call builds the cone averages' table);
* the cone average of 500 samples of a sharp lobe (tests/test_instrument.py);
* ``gonio-capture --check`` refusing an unbounded plan, in-process, and ``Plan.validate`` refusing two
  (tests/test_acq_validation.py);
* ``load_inputs`` of a 100 MB generic table in a child process, with its peak memory
  (tests/test_input_robustness.py).

Elsewhere: the check of the largest plan is benchmarks/bench_check.py, the reading of the real Zemax file
benchmarks/bench_formats.py, the instrument model per sample benchmarks/bench_instrument.py.

Run: .venv/bin/python benchmarks/bench_test_timings.py [--repeats 3] [--skip-big]
"""

from __future__ import annotations

import argparse
import contextlib
import io
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np
import tomli_w

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.core.models import Colour, Lambert, Material, Microfacet  # noqa: E402
from reconstruction.core.slicedata import Slice  # noqa: E402
from reconstruction.instrument.response import Instrument, instrument_average  # noqa: E402
from reconstruction.methods.fit import reconstruct_fit  # noqa: E402


def timed(fn: Callable[[], object], repeats: int) -> tuple[float, float, float]:
    """(first call's wall seconds, best wall, best CPU) of ``repeats`` calls."""
    walls, cpus = [], []
    for _ in range(repeats):  # a few repeats
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        walls.append(time.perf_counter() - t0)
        cpus.append(time.process_time() - c0)
    return walls[0], min(walls), min(cpus)


def line(label: str, t: tuple[float, float, float], bound: str) -> None:
    print(f"{label}: first {t[0]:.3f} s, best {t[1]:.3f} s wall / {t[2]:.3f} s CPU   ({bound})")


def fit_through_a_cone(repeats: int) -> None:
    inst = Instrument(1e-3)
    mat = Material("m", [Lambert(Colour(np.array([0.02]))), Microfacet(Colour(np.array([0.95])), alpha=0.005)])
    ti, to = np.meshgrid([0.0, 20.0, 40.0, 60.0], np.arange(-80.0, 81.0, 2.0), indexing="ij")
    ti, to = ti.ravel(), to.ravel()
    keep = np.abs(to + ti) > 4
    ti, to = ti[keep], to[keep]
    v = instrument_average(mat, ti, to, inst)
    std = 0.01 * v + 1e-4
    s = Slice(ti, to, v + np.random.default_rng(1).normal(size=v.shape) * std, ["value"], std,
              meta={"instrument": inst.to_meta()})
    line("fit, alpha 0.005 through a 1e-3 sr cone", timed(lambda: reconstruct_fit(s), repeats),
         "the test held < 3 s; the first call of a process builds the cone averages' table unless cached")


def cone_average_of_500(repeats: int) -> None:
    mat = Material("m", [Lambert(Colour(np.array([0.02]))), Microfacet(Colour(np.array([0.97, 0.95, 0.9])),
                                                                       alpha=1e-3)])
    inst = Instrument.from_half_angle(1.0)
    ti = np.repeat(np.linspace(0.0, 80.0, 10), 50)
    to = ti + np.tile(np.linspace(-3.0, 3.0, 50), 10)
    instrument_average(mat.eval, ti[:5], to[:5], inst)  # warm up
    line("cone average of 500 samples of a sharp lobe", timed(lambda: instrument_average(mat.eval, ti, to, inst),
                                                              repeats), "the test held < 2 s")


def refused_plans(repeats: int) -> None:
    import tomllib

    from acquisition import Bench, Plan, PlanError
    from acquisition.cli import main

    with tempfile.TemporaryDirectory() as d:
        raw = tomllib.loads((ROOT / "configs" / "simulated.toml").read_text())
        raw["plan"]["theta_o_step_deg"] = 1e-7
        cfg = Path(d) / "c.toml"
        cfg.write_text(tomli_w.dumps(raw))

        def check() -> None:
            with contextlib.redirect_stderr(io.StringIO()), contextlib.redirect_stdout(io.StringIO()):
                assert main(["--config", str(cfg), "--check"]) == 2

        line("gonio-capture --check refusing a plan finer than the axes (in-process)", timed(check, repeats),
             "the test held < 1 s")
        bench = Bench.from_config(ROOT / "configs" / "simulated.toml")

        def validate() -> None:
            for plan in (Plan.grid([30.0], -80.0, 80.0, 1e-7), Plan.grid(np.arange(0.0, 80.0, 0.2), -80.0, 80.0, 0.1)):
                try:
                    plan.validate(bench.geometry)
                except PlanError:
                    continue
                raise AssertionError("the plan was not refused")

        line("Plan.validate refusing two unbounded plans", timed(validate, repeats), "the test held < 1 s")


def big_table() -> None:
    with tempfile.TemporaryDirectory() as d:
        big = Path(d) / "big.csv"
        n_to, n_ti = 1000, 100_000_000 // (1000 * 124)
        ti = np.repeat(np.linspace(0.0, 80.0, n_ti), n_to)
        to = np.tile(np.linspace(-85.0, 85.0, n_to), n_ti)
        v = 0.1 + 0.01 * np.random.default_rng(1).random((ti.size, 3))
        with open(big, "w") as fh:
            fh.write("theta_i_deg,theta_o_deg,R,G,B,R_std,G_std,B_std\n")
            np.savetxt(fh, np.column_stack([ti, to, v, 0.01 * v]), delimiter=",", fmt="%.12g")
        # the child's own peak (VmHWM): getrusage's ru_maxrss survives exec and can be the parent's size at the fork
        code = ("import re, sys, time; from reconstruction.formats.inputs import load_inputs; "
                "t = time.perf_counter(); c = time.process_time(); s = load_inputs([sys.argv[1]],"
                " quantity='brdf').slice; "
                "print(len(s), time.perf_counter() - t, time.process_time() - c, "
                "re.search(r'VmHWM:\\s+(\\d+)', open('/proc/self/status').read()).group(1))")
        r = subprocess.run([sys.executable, "-c", code, str(big)], capture_output=True, text=True, cwd=ROOT,
                           check=True)
        n, wall, cpu, rss = r.stdout.split()
        print(f"load_inputs of a {big.stat().st_size / 1e6:.0f} MB table ({int(n):,} samples): {float(wall):.2f} s "
              f"wall / {float(cpu):.2f} s CPU, peak {int(rss) / 1e3:.0f} MB   (issue 11: < 20 s and < 1 GB)")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--skip-big", action="store_true", help="skip the 100 MB table (written first, a few seconds)")
    args = ap.parse_args()
    fit_through_a_cone(args.repeats)
    cone_average_of_500(args.repeats)
    refused_plans(args.repeats)
    if not args.skip_big:
        big_table()


if __name__ == "__main__":
    main()
