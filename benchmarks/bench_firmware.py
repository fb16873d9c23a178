"""The demo capture (configs/simulated.toml, 224 samples) on the all-Python simulator and with the detector board's
real firmware on an emulated ATmega328P (``gonio-sim serve --detector-firmware``): wall time, simulated bench
time, samples per second of wall time, and how far the firmware's samples are from the Python simulator's (same
seed: the same noise is drawn; what differs is the board's 10-bit ADC, summed over 80 dithered conversions a
repeat, and its timing), in units of each sample's std (``value_std`` of the Python run).

The firmware is built with the sample changer (``make SAMPLE_CHANGER=1``): the demo calibrates against a white
reference, which a board without one would ask the operator to put in place. The board reads the photodiode
through the amplifier's circuit (hardware/frontend/transfer.json, made by ngspice); so that both runs read the same
circuit, the benchmark captures a copy of the config with ``[simulator].frontend = "netlist"`` (in ``--out``).

Run: .venv/bin/python benchmarks/bench_firmware.py [--out out/bench-firmware] [--config configs/simulated.toml]
(about 30 s: two captures; needs gcc-avr, avr-libc, simavr, libsimavr-dev, libsimavrparts1)
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from simulator.devices import firmware as fw  # noqa: E402


def capture(config: Path, out: Path, elf: Path | None) -> dict:
    """One gonio-capture run (a child process, as a user runs it); its --json result plus the wall time (s)."""
    shutil.rmtree(out, ignore_errors=True)
    env = dict(os.environ)
    env.pop("GONIO_SIM_DETECTOR_FIRMWARE", None)
    if elf is not None:
        env["GONIO_SIM_DETECTOR_FIRMWARE"] = str(elf)
    exe = Path(sys.executable).with_name("gonio-capture")
    argv = [str(exe)] if exe.is_file() else [sys.executable, "-m", "acquisition.cli"]
    t0 = time.perf_counter()
    r = subprocess.run([*argv, "--config", str(config), "--out", str(out), "--no-progress", "--json"],
                       capture_output=True, text=True, env=env, cwd=ROOT)
    wall = time.perf_counter() - t0
    if r.returncode != 0:
        raise SystemExit(f"capture into {out} failed ({r.returncode}): {r.stderr.strip()[-400:]}")
    res = json.loads(r.stdout)
    res["wall_total_s"] = wall
    return res


def read_slice(path: Path) -> dict[tuple[float, float], tuple[float, float]]:
    """(theta_i, theta_o) -> (value, value_std) of a slice.csv."""
    rows = [ln for ln in path.read_text().splitlines() if ln and not ln.startswith("#")][1:]
    out = {}
    for ln in rows:
        ti, to, v, s = (float(x) for x in ln.split(",")[:4])
        out[(ti, to)] = (v, s)
    return out


def netlist_config(config: Path, dest: Path) -> Path:
    """A copy of ``config`` whose Python controller reads the amplifier's circuit, as the board does."""
    import tomli_w

    try:
        import tomllib
    except ImportError:  # Python 3.10
        import tomli as tomllib

    raw = tomllib.loads(config.read_text(encoding="utf-8"))
    raw.setdefault("simulator", {})["frontend"] = "netlist"
    dest.parent.mkdir(parents=True, exist_ok=True)
    dest.write_text(tomli_w.dumps(raw), encoding="utf-8")
    return dest


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--config", default=str(ROOT / "configs" / "simulated.toml"))
    ap.add_argument("--out", default=str(ROOT / "out" / "bench-firmware"))
    args = ap.parse_args()
    problem = fw.toolchain_problem()
    if problem:
        print(f"bench_firmware: {problem}", file=sys.stderr)
        return 2
    out = Path(args.out)
    elf = fw.build_firmware(out / "firmware", sample_changer=True)
    config = netlist_config(Path(args.config), out / "netlist.toml")
    runs = {"python": capture(config, out / "python", None),
            "firmware": capture(config, out / "firmware-capture", elf)}
    a = read_slice(out / "python" / "slice.csv")
    b = read_slice(out / "firmware-capture" / "slice.csv")
    keys = sorted(set(a) & set(b))
    z = np.array([(b[k][0] - a[k][0]) / a[k][1] for k in keys])
    rel = np.array([abs(b[k][0] - a[k][0]) / abs(a[k][0]) for k in keys])
    print(f"demo capture {args.config}: {len(a)} samples (Python simulator), {len(b)} (firmware), {len(keys)} in "
          "common")
    print(f"{'detector':<10} {'wall s':>8} {'bench s':>9} {'samples/s':>10}")
    for name, r in runs.items():
        n = r.get("samples_new", len(a if name == "python" else b))
        print(f"{name:<10} {r['wall_total_s']:8.2f} {r['bench_time_s']:9.2f} {n / r['wall_total_s']:10.1f}")
    print(f"firmware - Python, in units of the sample's std: largest |z| {np.max(np.abs(z)):.2f}, rms "
          f"{np.sqrt(np.mean(z ** 2)):.2f}, mean {np.mean(z):+.2f}; largest relative difference {np.max(rel):.2e}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
