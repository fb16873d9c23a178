"""The time model against the simulated bench: ``gonio-capture --check``'s estimate and the capture's estimate
(with adaptive refinement's rounds, estimated as they are planned) beside the simulated bench time the capture
took, for the shipped configs and plans.

The real benches' files (``configs/dynamixel-bench.toml``, ``configs/serial-bench.toml``) are run as simulated
benches of the same mechanics: ``transport = "simulated"`` (``[bench].motion`` kept), the simulated stepper moving
at the file's ``[motion]`` speed and acceleration, the material of ``configs/simulated.toml``. Each capture runs
the real drivers against ``gonio-sim serve`` through pseudo-terminals; ``--time-scale 0`` (the default) lets
simulated time jump, so the figures are exact and a capture takes a second or two of wall time; ``--time-scale
K`` runs simulated time at K x wall time, where the drivers' polling and the software's own time become bench
time too, as on a real bench (K = 1). The model counts the polling (a move is over at the first poll after it) and
a constant software time per reading measured at K = 1 (``acquisition.plans.geometry.HOST_S_PER_READING``); at K > 1
the software's real time is magnified K times while the arms move K times faster, and the estimate falls short.

    .venv/bin/python benchmarks/bench_time_model.py [--time-scale 0] [--quick]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import tomli_w

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from acquisition import Bench  # noqa: E402


def simulated(name: str, time_scale: float, motion: str | None = None, plan: dict[str, Any] | None = None,
              material: dict[str, Any] | None = None, simulator: dict[str, Any] | None = None) -> dict[str, Any]:
    """The bench file ``configs/NAME`` as a simulated bench of the same mechanics (see the module docstring)."""
    raw = tomllib.loads((REPO / "configs" / name).read_text())
    base = tomllib.loads((REPO / "configs" / "simulated.toml").read_text())
    b = raw["bench"]
    if b.get("transport") != "simulated":
        b.update(transport="simulated", motion="serial" if b["transport"] == "serial" else "dynamixel",
                 dynamixel_port="", serial_port="")
        raw.setdefault("material", base["material"])
        m = raw["motion"]
        raw["simulator"] = {"stepper_velocity_deg_s": m.get("velocity_deg_s", 60.0),
                            "stepper_acceleration_deg_s2": m.get("acceleration_deg_s2", 240.0)}
    if motion is not None:
        b["motion"] = motion
    raw.setdefault("simulator", {})["time_scale"] = time_scale
    if plan is not None:
        raw["plan"] = {**raw["plan"], **plan}
    if material is not None:
        raw["material"] = material
    raw["simulator"].update(simulator or {})
    return raw


def run(label: str, raw: dict[str, Any], tmp: Path) -> dict[str, Any]:
    """--check's estimate, then a capture: its estimate (with the rounds) and its simulated bench time."""
    cfg = tmp / f"{label}.toml"
    cfg.write_text(tomli_w.dumps(raw))
    bench = Bench.from_config(cfg)
    plan = bench.plan()
    chk = plan.validate(bench.geometry)
    check = plan.estimate(bench.geometry, bench.cfg.detector.integration_time_s, chk.measurable, cfg=bench.cfg)
    t0 = time.monotonic()
    r = bench.capture(plan, out=tmp / label, progress=False, handle_signals=False)
    wall = time.monotonic() - t0
    r.raise_for_status()
    rec = json.loads((tmp / label / "capture.json").read_text())
    est, actual = rec["estimate"]["total_s"], rec["totals"]["bench_time_s"]
    return {"label": label, "points": r.samples_new, "check_s": check["total_s"], "estimate_s": est,
            "refinement_s": rec["estimate"]["refinement_s"], "bench_s": actual, "dev": (est - actual) / actual,
            "motion_est": rec["estimate"]["motion_s"], "motion": r.motion_s, "wall_s": wall,
            "ranged": r.auto_ranged}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--time-scale", type=float, default=0.0, help="simulated time x wall time (0: as fast as "
                                                                    "possible)")
    ap.add_argument("--quick", action="store_true", help="only the two simulated benches' shipped plans")
    args = ap.parse_args(argv)
    ts = args.time_scale
    cases = [
        ("simulated.toml (Dynamixel)", simulated("simulated.toml", ts)),
        ("simulated.toml, motion = serial (stepper)", simulated("simulated.toml", ts, motion="serial")),
        ("serial-bench.toml (stepper, spectrometer, adaptive)", simulated("serial-bench.toml", ts)),
    ]
    if not args.quick:
        cases += [
            ("simulated.toml, adaptive plan", simulated("simulated.toml", ts, plan={
                "theta_o_step_deg": 8.0, "adaptive": {"coarse_step_deg": 8.0, "min_step_deg": 1.0,
                                                      "tolerance": 0.05}})),
            ("dynamixel-bench.toml (Dynamixel, 1 deg steps)", simulated("dynamixel-bench.toml", ts)),
            ("simulated.toml, sharp ggx (alpha 0.005), 1 deg steps", simulated(
                "simulated.toml", ts, plan={"theta_o_step_deg": 1.0}, material={"name": "sharp", "lobes": [
                    {"type": "lambert", "albedo": 0.1}, {"type": "ggx", "alpha": 0.005, "specular": 0.9}]})),
            ("simulated.toml, theta_i 40, source_power 1e9 (every point above the range)", simulated(
                "simulated.toml", ts, plan={"theta_i_deg": [40.0]}, simulator={"source_power": 1e9})),
        ]
    print(f"time scale {ts:g} ({'simulated time jumps' if ts == 0 else f'{ts:g} x wall time'})")
    print("| bench and plan | points | auto-ranged | --check (s) | estimate (s) | of it refinement (s) | simulated "
          "bench time (s) | estimate - bench | motion estimate / simulated (s) | wall (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|")
    worst = 0.0
    with tempfile.TemporaryDirectory() as d:
        for k, (label, raw) in enumerate(cases):
            r = run(f"case{k}", raw, Path(d))
            worst = max(worst, abs(r["dev"]))
            print(f"| {label} | {r['points']} | {r['ranged']} | {r['check_s']:.2f} | {r['estimate_s']:.2f} | "
                  f"{r['refinement_s']:.2f} | {r['bench_s']:.2f} | {100 * r['dev']:+.2f} % | "
                  f"{r['motion_est']:.2f} / {r['motion']:.2f} | {r['wall_s']:.1f} |", flush=True)
    print(f"largest deviation {100 * worst:.2f} %")
    return 0


if __name__ == "__main__":
    sys.exit(main())
