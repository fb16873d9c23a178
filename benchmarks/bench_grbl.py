"""The demo plan on a GRBL bench whose arms run on GRBL 1.1h's own code (grbl-sim with the project's configuration
and shim, ``make -C firmware/grbl sim``, built from ../shared/grbl into a temporary folder): per move, the bench
time grbl-sim simulated against the time model's estimate, and the position error at each sample read back from
``MPos``.

The bench is configs/grbl-bench.toml's mechanics (44.44 steps/deg, $110 = 3600 deg/min, $120 = 240 deg/s^2, both
arms) without switches (homing and soft limits off: the arms start at machine 0 = 0 deg); the plan is
configs/simulated.toml's ``[plan]`` (the demo: 20/40/60 deg incidence, -80..80 every 2 deg) in the capture's own
order, or ``--short`` (30/60 deg, every 10 deg). The arms are moved by ``acquisition.devices.grbl.GrblAxes``
exactly as a capture moves them (the detector is left out: it does not change the motion).

Simulated time: grbl-sim's step output (``-r 0.005``) times each block: it starts at the counters printed with the
block's header (the arms at rest) and ends at its last sample plus the time its dominant axis needs for the steps
left at the block's deceleration (grbl-sim stops sampling a block when its last segments are prepared, up to a
few 10-ms segments before its last step). Wall time is what the driver waited (``G0`` sent -> ``Idle`` in
position), which includes grbl-sim's slowness (it simulates every tick of the 16 MHz clock, on one thread) and
the polling.

    .venv/bin/python benchmarks/bench_grbl.py [--short]
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from acquisition.config import load_config  # noqa: E402
from acquisition.devices.grbl import GrblAxes  # noqa: E402
from acquisition.plans.geometry import Geometry  # noqa: E402
from acquisition.plans.ordering import order_points  # noqa: E402
from acquisition.plans.plan import Plan  # noqa: E402
from simulator.world.stepfile import GrblSimTrack  # noqa: E402
from tests import grbl_harness as gh  # noqa: E402

REPORT_S = 0.005


def block_times(steps_path: Path) -> list[tuple[float, float, int, int]]:
    """Per block of grbl-sim's step file: (start time, last sample time, last x, last y)."""
    out: list[list[float]] = []
    samples: list[list[float]] = []  # the lines since the last header
    for ln in steps_path.read_text().splitlines():
        ln = ln.strip()
        if ln.startswith("# block number"):
            # the line printed with the header is the new block's start (the arms at rest), not the last block's
            start = samples.pop() if samples else [0.0, 0.0, 0.0]
            if out and samples:
                out[-1][1:] = samples[-1]
            out.append([start[0], math.nan, 0, 0])
            samples = []
        elif ln:
            p = ln.replace(",", " ").split()
            samples.append([float(p[0]), float(p[1]), float(p[2])])
    if out and samples:
        out[-1][1:] = samples[-1]
    return [(a, b, int(x), int(y)) for a, b, x, y in out]


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--short", action="store_true", help="30/60 deg incidence, every 10 deg (instead of the demo)")
    ap.add_argument("--moves", action="store_true", help="print every move: goal, model, grbl-sim (s)")
    args = ap.parse_args()
    why = gh.missing()
    if why:
        print(f"bench_grbl: cannot run: {why}", file=sys.stderr)
        return 2
    cfg = load_config(REPO / "configs" / "grbl-bench.toml")
    import dataclasses

    import msgspec

    from reconstruction.schema.bench import GrblTable

    axes = {n: msgspec.structs.replace(a, zero_offset=0.0) for n, a in cfg.axes.items()}
    motion = msgspec.structs.replace(cfg.motion, grbl=GrblTable(boot_s=0.3), poll_interval_s=0.02, timeout_s=120.0)
    geom = dataclasses.replace(Geometry.from_config(cfg), light=axes["light"], detector=axes["detector"], arrive_s=0.0,
                               poll_s=0.0, host_s=0.0)
    demo = load_config(REPO / "configs" / "simulated.toml").plan
    plan = Plan.from_config(demo, REPO / "configs")
    if args.short:
        plan = Plan.from_config(msgspec.structs.replace(demo, theta_i_deg=(30.0, 60.0), theta_o_step_deg=10.0),
                                REPO / "configs")
    pts = order_points(plan.check(geom).measurable, geom)
    goals = [geom.park, *pts, geom.park]
    with tempfile.TemporaryDirectory() as tmp:
        exe = gh.build(Path(tmp) / "build")
        sim = gh.GrblSim(exe, Path(tmp) / "run", report_s=REPORT_S)
        try:
            sim.wait_ready()
            ax_l, ax_d = axes["light"], axes["detector"]
            for n, v in {20: 0, 22: 0, 100: ax_l.units_per_deg, 101: ax_d.units_per_deg,
                         110: motion.velocity_deg_s * 60, 111: motion.velocity_deg_s * 60,
                         120: motion.acceleration_deg_s2, 121: motion.acceleration_deg_s2}.items():
                sim.send_line(f"${n}={v:.6g}")
            sim.send_line("$X")  # our build powers up locked (homing on by default); no switches here
            sim.release()
            drv = GrblAxes(sim.port, axes, motion)
            drv.connect()
            track = GrblSimTrack(sim.steps_path, sim.blocks_path, ax_l, ax_d)
            wall, err, track_err = [], [], []
            t0 = time.monotonic()
            for g in goals:
                t = time.monotonic()
                try:
                    drv.move({"light": g[0], "detector": g[1]}, check_cancel=False)
                except Exception as exc:  # noqa: BLE001 - report where grbl-sim stopped, then give up
                    print(f"bench_grbl: move {len(wall)} to {g} failed: {exc}; GRBL says {drv.status().raw}",
                          file=sys.stderr)
                    return 1
                wall.append(time.monotonic() - t)
                pos = drv.positions()
                err.append((pos["light"] - g[0], pos["detector"] - g[1]))
                track_err.append(np.subtract(track(0.0), (pos["light"], pos["detector"])))
            wall_total = time.monotonic() - t0
            time.sleep(0.2)
            blocks = block_times(sim.steps_path)
        finally:
            sim.close()
    est = [geom.move_time(a, b) for a, b in zip([(0.0, 0.0), *goals[:-1]], goals, strict=True)]
    moved = [i for i, e in enumerate(est) if e > 0]
    if len(blocks) != len(moved):
        print(f"bench_grbl: {len(blocks)} blocks in grbl-sim's step file for {len(moved)} moves", file=sys.stderr)
        return 1
    sim_t: list[float] = []
    prev = np.zeros(2)
    steps_goal = [np.round([ax_l.units_per_deg * g[0], ax_d.units_per_deg * g[1]]) for g in goals]
    for (start, last_t, x, y), i in zip(blocks, moved, strict=True):
        d = np.abs(steps_goal[i] - (steps_goal[i - 1] if i else prev))
        upd = (ax_l.units_per_deg, ax_d.units_per_deg)
        acc = min(motion.acceleration_deg_s2 * u / di for u, di in zip(upd, d, strict=True) if di > 0)
        k = int(np.argmax(d))
        rem = abs(steps_goal[i][k] - (x, y)[k])
        sim_t.append(last_t - start + math.sqrt(2 * rem / (acc * d[k])))
    # the first block has no start line (grbl-sim prints one only from the second block on): left out
    blocks, moved, sim_s = blocks[1:], moved[1:], np.array(sim_t[1:])
    est_m = np.array([est[i] for i in moved])
    if args.moves:
        for (start, last_t, x, y), i, t in zip(blocks, moved, sim_s, strict=True):
            print(f"{goals[i - 1] if i else (0.0, 0.0)} -> {goals[i]}: model {est[i]:.3f} s, grbl-sim {t:.3f} s "
                  f"(start {start:.3f}, last sample {last_t:.3f}, at {x}, {y})")
    e = np.array(err)
    print(f"plan: {'--short' if args.short else 'the demo (configs/simulated.toml [plan])'}: {len(pts)} points, "
          f"{len(moved)} moves timed (points, park; the first move, from power-up, is not) on grbl-sim (GRBL 1.1h), "
          "44.44 steps/deg, 60 deg/s, 240 deg/s^2")
    print(f"motion time, grbl-sim's clock: {sim_s.sum():.2f} s; time model: {est_m.sum():.2f} s "
          f"({100 * (est_m.sum() / sim_s.sum() - 1):+.2f} %)")
    rel = est_m / sim_s - 1
    print(f"  per move: model - grbl-sim = {np.mean(est_m - sim_s) * 1e3:+.1f} ms mean, "
          f"{np.max(np.abs(est_m - sim_s)) * 1e3:.1f} ms at most ({100 * np.max(np.abs(rel)):.1f} % at most)")
    print(f"wall time waiting for the moves: {sum(wall):.1f} s of {wall_total:.1f} s "
          f"(grbl-sim ran {sim_s.sum() / sum(wall[1:]):.2f} x real time here, polls included)")
    print(f"position error at each sample, MPos - goal: max {np.abs(e).max():.4f} deg, rms "
          f"{np.sqrt(np.mean(e ** 2)):.4f} deg (one step = {1 / ax_l.units_per_deg:.4f} deg)")
    print(f"detector's angles from grbl-sim's step output - MPos: max {np.abs(np.array(track_err)).max():.2g} deg")
    return 0


if __name__ == "__main__":
    sys.exit(main())
