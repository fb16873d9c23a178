"""Where users wait (issue 26): ``auto`` against ``bivariate``, ``--html`` against none, and the test suite.

Every figure is a whole process, as a user runs it: ``gonio-reconstruct`` on the demo capture (made first with
``gonio-capture --config configs/simulated.toml`` into a temporary folder unless ``--capture`` names one), with
``--method bivariate``, ``--method auto``, ``--method auto --html`` and, for reading the figures, ``--method auto
--no-conservative``. The runs are interleaved (bivariate, auto, auto --html, auto unbounded, then again ``--repeats``
times) so that a change of the machine's load falls on all of them alike; the
table gives each one's median and best wall time and its CPU time (user + system of the child process, which
other jobs on the machine do not inflate), and the ratios the targets are about:

* auto / bivariate, whole process: at most 2;
* auto --html / auto: at most 1.5 (the HTML report adds at most 50 %).

``--prior DIR`` (repeatable: the folders of one prior) also times ``--method prior --prior DIR ...`` on the demo
capture with an empty cache (a fresh ``XDG_CACHE_HOME``: the prior's folders tabulated and cached, target 10 s on
an idle machine), then again from that cache, and gives the cache's size (target 20 MB for the 141 real
materials).

The project's bytecode is written first (:func:`compile_project`), so that every run is timed as a user's runs
after the first are, whatever ``PYTHONDONTWRITEBYTECODE`` says.

``--suite`` also times the README's second command (``python3 -m venv .venv && .venv/bin/pip install -q -e
'.[test]' && .venv/bin/python -m pytest -q``) from a clean clone of this repository's HEAD in a temporary folder:
install and tests, wall time, target 5 minutes on the 2-core machine. The load average (1 / 5 / 15 min) is printed
beside the figures: absolute times are only comparable on an idle machine, the ratios on any.

Run: .venv/bin/python benchmarks/bench_speed.py [--repeats 5] [--capture out/demo] [--prior DIR ...] [--suite]
"""

from __future__ import annotations

import argparse
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
BIN = Path(sys.executable).parent
TARGETS = {"auto / bivariate": 2.0, "auto --html / auto": 1.5}


def load() -> str:
    return " / ".join(f"{x:.1f}" for x in os.getloadavg())


def tool(name: str) -> list[str]:
    """The console script beside this interpreter, or its module run by it."""
    exe = BIN / name
    module = {"gonio-capture": "acquisition.cli", "gonio-reconstruct": "reconstruction.cli"}[name]
    return [str(exe)] if exe.exists() else [sys.executable, "-m", module]


def timed(argv: list[str], cwd: Path, env: dict[str, str] | None = None) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the child: user + system) of one run of ``argv``; exits on failure."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t0 = time.perf_counter()
    p = subprocess.run(argv, cwd=cwd, capture_output=True, text=True, env=env)
    wall = time.perf_counter() - t0
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if p.returncode != 0:
        sys.exit(f"bench_speed: {' '.join(argv)} failed (status {p.returncode}):\n{p.stderr[-2000:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def reconstruction_runs(capture: Path, work: Path, repeats: int) -> dict[str, list[tuple[float, float]]]:
    """{label: [(wall, cpu), ...]} of the three reconstructions, interleaved."""
    csv = str(capture / "slice.csv")
    runs = {"bivariate": [*tool("gonio-reconstruct"), csv, "--method", "bivariate", "--out", "b.binary"],
            "auto": [*tool("gonio-reconstruct"), csv, "--method", "auto", "--out", "a.binary"],
            "auto --html": [*tool("gonio-reconstruct"), csv, "--method", "auto", "--out", "h.binary",
                            "--html", "h.html"],
            # for reading the figures: auto without its conservative bound (without a prior, the analytic family's
            # posterior it needs is most of what auto costs beyond its methods)
            "auto unbounded": [*tool("gonio-reconstruct"), csv, "--method", "auto", "--out", "u.binary",
                               "--no-conservative"]}
    for argv in runs.values():  # a first run of each, not counted: the file cache and bytecode warm for all alike
        timed(argv, work)
    out: dict[str, list[tuple[float, float]]] = {k: [] for k in runs}
    for _ in range(repeats):  # a few rounds
        for label, argv in runs.items():
            out[label].append(timed(argv, work))
    return out


def prior_runs(capture: Path, work: Path, folders: list[Path]) -> tuple[tuple[float, float], tuple[float, float],
                                                                         int]:
    """((wall, cpu) of the first run, with an empty cache; (wall, cpu) of a run from that cache; the cache's bytes)
    of ``--method prior`` with ``folders`` on the demo capture."""
    cache = work / "cache"
    env = {**os.environ, "XDG_CACHE_HOME": str(cache)}
    argv = [*tool("gonio-reconstruct"), str(capture / "slice.csv"), "--method", "prior", "--out", "p.binary"]
    for f in folders:  # one or two
        argv += ["--prior", str(f.resolve())]
    first = timed(argv, work, env)
    size = sum(p.stat().st_size for p in cache.rglob("*") if p.is_file())
    return first, timed(argv, work, env), size


def suite(work: Path) -> tuple[float, int]:
    """(wall seconds, exit status) of the README's second command in a clean clone of HEAD."""
    clone = work / "clone"
    subprocess.run(["git", "clone", "-q", str(ROOT), str(clone)], check=True)
    cmd = "python3 -m venv .venv && .venv/bin/pip install -q -e '.[test]' && .venv/bin/python -m pytest -q"
    t0 = time.perf_counter()
    p = subprocess.run(["bash", "-c", cmd], cwd=clone, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    tail = (p.stdout.strip().splitlines() or [""])[-1]
    print(f"suite: {tail}")
    return wall, p.returncode


def compile_project() -> None:
    """Write the bytecode of the project's packages first, as any first run does where Python may write it: the
    runs timed are a user's second run, not one that compiles the modules changed since the last (with
    ``PYTHONDONTWRITEBYTECODE`` set, every run would compile them: 0.03-0.1 s each)."""
    import compileall

    for pkg in ("reconstruction", "acquisition", "simulator"):
        compileall.compile_dir(ROOT / pkg, quiet=1)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--repeats", type=int, default=5, help="rounds of the three reconstructions (default 5)")
    ap.add_argument("--capture", type=Path, help="a finished demo capture (default: captured anew)")
    ap.add_argument("--prior", type=Path, action="append", default=[], metavar="DIR",
                    help="also time --method prior with these folders, first with an empty cache (repeatable)")
    ap.add_argument("--suite", action="store_true", help="also time the README's test command from a clean clone")
    args = ap.parse_args()
    print(f"{os.cpu_count()} CPUs; load average {load()} (1 / 5 / 15 min) at the start")
    compile_project()
    with tempfile.TemporaryDirectory(prefix="bench_speed_") as tmp:
        work = Path(tmp)
        capture = args.capture
        if capture is None:
            capture = work / "demo"
            timed([*tool("gonio-capture"), "--config", str(ROOT / "configs" / "simulated.toml"), "--out",
                   str(capture)], ROOT)
        runs = reconstruction_runs(capture.resolve(), work, args.repeats)
        print(f"\ngonio-reconstruct on the demo capture ({capture}), {args.repeats} interleaved rounds; "
              f"load average {load()} after them")
        print(f"{'run':<14} {'median wall':>12} {'best wall':>10} {'median CPU':>11}")
        med = {}
        for label, rs in runs.items():
            walls, cpus = [r[0] for r in rs], [r[1] for r in rs]
            med[label] = (statistics.median(walls), min(walls), statistics.median(cpus))
            print(f"{label:<14} {med[label][0]:>10.2f} s {med[label][1]:>8.2f} s {med[label][2]:>9.2f} s")
        print(f"\n{'ratio':<20} {'median wall':>12} {'best wall':>10} {'CPU':>6} {'target':>8}")
        for name, (a, b) in {"auto / bivariate": ("auto", "bivariate"),
                             "auto --html / auto": ("auto --html", "auto"),
                             "auto unbounded / biv.": ("auto unbounded", "bivariate")}.items():
            r = [med[a][k] / med[b][k] for k in range(3)]
            if name not in TARGETS:  # for reading, no target
                print(f"{name:<20} {r[0]:>12.2f} {r[1]:>10.2f} {r[2]:>6.2f}")
                continue
            ok = "ok" if r[0] <= TARGETS[name] else "OVER"
            print(f"{name:<20} {r[0]:>12.2f} {r[1]:>10.2f} {r[2]:>6.2f} {'<= ' + format(TARGETS[name], 'g'):>8} "
                  f"{ok}")
        if args.prior:
            missing = [str(f) for f in args.prior if not f.is_dir()]
            if missing:
                sys.exit(f"bench_speed: --prior {', '.join(missing)}: not a folder")
            first, again, size = prior_runs(capture.resolve(), work, args.prior)
            print(f"\n--method prior with {', '.join(str(f) for f in args.prior)} (load average {load()} after):")
            print(f"{'first run (empty cache)':<24} {first[0]:>8.2f} s wall {first[1]:>6.2f} s CPU (target <= 10 s)")
            print(f"{'from the cache':<24} {again[0]:>8.2f} s wall {again[1]:>6.2f} s CPU")
            print(f"{'cache':<24} {size / 1e6:>8.1f} MB (target <= 20 MB for the 141 real materials)")
        if args.suite:
            if shutil.which("git") is None:
                sys.exit("bench_speed: --suite needs git (it clones HEAD)")
            print(f"\nthe README's test command from a clean clone of HEAD (load average {load()} at the start) ...")
            wall, status = suite(work)
            print(f"{'suite (install + tests)':<24} {wall:>8.0f} s wall (target <= 300 s), exit status {status}; "
                  f"load average {load()} at the end")


if __name__ == "__main__":
    main()
