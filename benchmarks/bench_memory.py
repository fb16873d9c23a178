"""Peak memory of ``gonio-reconstruct`` per method on large slices (issue 49, item 7), a process per run.

A synthetic slice of ``--rows`` rows (the simulated bench's material, ``--incidences`` incidences, theta_o every
few hundredths of a degree, 2 % noise) is written to a temporary folder; then, for each method, ``python -m
reconstruction.cli SLICE --method M --out M.binary`` runs as a user runs it, and its peak is measured two ways:
``ru_maxrss`` of the process (``os.wait4``: the largest of it and the children it waited for) and the largest sum
of the resident memory of it and its children (``/proc``, sampled every 50 ms: auto's forked child counted with
it). ``read`` is the input step alone (``reconstruction.formats.inputs.load_inputs``: the reader and the
thinning). The table gives both peaks in MB and per million rows of input.

``--largest`` measures instead the largest slice file the reader accepts: the shortest rows (``1.125,-3.07,0.1,
0.01,1,0``: one channel, angles in hundredths) up to ``MAX_INPUT_BYTES`` (about 10.6 million rows).

Run: .venv/bin/python benchmarks/bench_memory.py [--rows 250000 1000000] [--methods read fit auto ...] [--largest]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
METHODS = ("read", "fit", "microfacet", "revolve", "bivariate", "auto")


def write_big(path: Path, rows: int, incidences: int) -> int:
    """A synthetic slice of about ``rows`` rows in ``path``; its number of rows."""
    from reconstruction.core.models import Material
    from reconstruction.formats.slicefile import write_slice
    from reconstruction.synthetic import synthetic_slice

    inc = np.linspace(1.0, 85.0, incidences)
    to = np.linspace(-85.0, 85.0, int(np.ceil(rows / incidences * 1.03)))
    s = synthetic_slice(Material.from_toml(ROOT / "configs" / "simulated.toml"), inc, to, noise=0.02, seed=1)
    write_slice(path, s)
    return len(s)


def write_largest(path: Path) -> int:
    """The largest slice file the reader accepts, of the shortest rows; its number of rows."""
    from reconstruction.formats.slicefile import MAX_INPUT_BYTES

    n = 0
    with open(path, "w", encoding="utf-8", newline="\n") as fh:
        fh.write('# gonio-brdf slice\n# meta: {"format_version": 1, "quantity": "brdf"}\n'
                 "theta_i_deg,theta_o_deg,value,value_std,repeats,unix_time_s\n")
        size = fh.tell()
        to = np.round(np.arange(-89, 89, 0.01), 2)
        for a in np.round(np.arange(1, 89, 0.125), 3):  # one incidence at a time
            block = "".join(f"{a:g},{b:g},0.1,0.01,1,0\n" for b in to)
            if size + len(block) > MAX_INPUT_BYTES:
                break
            fh.write(block)
            size += len(block)
            n += to.size
    return n


def _tree_rss_kb(pid: int) -> int:
    """Resident kB of ``pid`` and its descendants (0 once gone)."""
    children: dict[int, list[int]] = {}
    rss: dict[int, int] = {}
    for d in Path("/proc").iterdir():
        if not d.name.isdigit():
            continue
        try:
            fields = (d / "stat").read_text().rsplit(")", 1)[1].split()
            children.setdefault(int(fields[1]), []).append(int(d.name))
            rss[int(d.name)] = int(fields[21]) * os.sysconf("SC_PAGE_SIZE") // 1024
        except (OSError, IndexError, ValueError):
            continue
    total, todo = 0, [pid]
    while todo:
        p = todo.pop()
        total += rss.get(p, 0)
        todo += children.get(p, [])
    return total


def measure(argv: list[str]) -> tuple[int, int, int, float, str]:
    """(exit status, ru_maxrss kB, the largest tree sum kB, wall s, stderr's last line) of ``argv``."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    t0 = time.perf_counter()
    proc = subprocess.Popen(argv, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    peak = [0]
    done = threading.Event()

    def sample() -> None:
        while not done.is_set():
            peak[0] = max(peak[0], _tree_rss_kb(proc.pid))
            done.wait(0.05)

    th = threading.Thread(target=sample, daemon=True)
    th.start()
    assert proc.stderr is not None
    err = proc.stderr.read()
    _, status, usage = os.wait4(proc.pid, 0)
    done.set()
    th.join()
    proc.stderr.close()
    last = err.strip().splitlines()[-1] if err.strip() else ""
    return os.waitstatus_to_exitcode(status), usage.ru_maxrss, peak[0], time.perf_counter() - t0, last


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, nargs="+", default=[250_000], help="rows of each slice (default 250000)")
    ap.add_argument("--incidences", type=int, default=400, help="incidences of each slice (default 400)")
    ap.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    ap.add_argument("--largest", action="store_true", help="the largest file the reader accepts, shortest rows")
    args = ap.parse_args()
    print(f"{'rows':>9} {'method':<11} {'ru_maxrss MB':>12} {'tree MB':>8} {'MB / M rows':>11} {'wall s':>7}  "
          "result")
    with tempfile.TemporaryDirectory(prefix="gonio-bench-memory-") as tmp:
        for rows in ([0] if args.largest else args.rows):
            path = Path(tmp) / f"slice-{rows}.csv"
            n = write_largest(path) if args.largest else write_big(path, rows, args.incidences)
            for m in args.methods:
                if m == "read":
                    code = ("import sys; from reconstruction.formats.inputs import load_inputs; "
                            "L = load_inputs([sys.argv[1]]); print(len(L.slice), 'samples used', file=sys.stderr)")
                    argv = [sys.executable, "-c", code, str(path)]
                else:
                    argv = [sys.executable, "-m", "reconstruction.cli", str(path), "--method", m, "--out",
                            str(Path(tmp) / f"{m}.binary")]
                status, maxrss, tree, wall, last = measure(argv)
                print(f"{n:>9} {m:<11} {maxrss / 1024:>12.0f} {tree / 1024:>8.0f} {tree / 1024 / n * 1e6:>11.0f} "
                      f"{wall:>7.1f}  {'exit ' + str(status) + ': ' if status else ''}{last[:90]}", flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
