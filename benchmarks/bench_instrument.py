"""What the physical instrument model costs a capture: the simulator's reading of a 500-point plan with the detector
cone and the source's divergence integrated (reconstruction.instrument.response.instrument_average) against the same
readings at the cone's centre (a point instrument, today's model before issue 10), per sample, for a smooth
material (the demo's blue plastic) and a mirror (ggx alpha 1e-3), and for the mirror's samples near its peak alone
(where the lobe rule runs; a lobe whose peak lies beyond 6 cone radii is smooth over the cone); then a whole
500-point capture of the shipped
config through the pseudo-terminals, per sample.

Each sample is one READ of 4 repeats at a new angle pair, as the simulator's serial controller does it
(``BenchPhysics.read``); the first call (imports, the band's sRGB basis) is timed apart.

    .venv/bin/python benchmarks/bench_instrument.py
"""

from __future__ import annotations

import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import tomli_w

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from reconstruction.instrument.response import Instrument  # noqa: E402
from simulator.config import config_from_dict  # noqa: E402
from simulator.world.physics import BenchPhysics  # noqa: E402

MIRROR = {"name": "mirror", "lobes": [{"type": "lambert", "albedo": 0.02},
                                      {"type": "ggx", "alpha": 1e-3, "specular": [0.97, 0.95, 0.9]}]}


def plan_pairs() -> np.ndarray:
    """(n, 2) angle pairs of a 500-point plan: 3 incidences, theta_o every 1 deg (off the blind spot)."""
    pairs = [(ti, to) for ti in (20.0, 40.0, 60.0) for to in np.arange(-80.0, 81.0, 1.0) if abs(ti + to) >= 6.0]
    return np.array(pairs[:500])


def near_peak_pairs() -> np.ndarray:
    """(n, 2) angle pairs within 3 deg of the specular direction only (the lobe rule's worst case)."""
    return np.array([(ti, ti + d) for ti in (20.0, 40.0, 60.0) for d in np.arange(-3.0, 3.01, 0.1)])


def per_sample(raw: dict, point: bool, repeats: int = 3, pairs: np.ndarray | None = None) -> tuple[float, float]:
    """(first call, median per sample after it) in seconds for the plan's readings."""
    pairs = plan_pairs() if pairs is None else pairs
    times = []
    first = 0.0
    for _ in range(repeats):
        ph = BenchPhysics(config_from_dict(raw), np.random.default_rng(0))
        if point:
            ph.instrument = Instrument(0.0, 0.0)  # f at the centre, the signal still over the cone's solid angle
        t0 = time.perf_counter()
        ph.read(np.full(4, pairs[0, 0]), np.full(4, pairs[0, 1]))
        first = time.perf_counter() - t0
        t0 = time.perf_counter()
        for ti, to in pairs[1:]:
            ph.read(np.full(4, ti), np.full(4, to))
        times.append((time.perf_counter() - t0) / (len(pairs) - 1))
    return first, statistics.median(times)


def capture_per_sample(raw: dict) -> tuple[float, int]:
    """Wall time per sample (s) of a whole capture of the 500-point plan (first to last slice row)."""
    from acquisition import Bench
    from reconstruction.formats.slicefile import read_slice

    raw = {**raw, "plan": {**raw["plan"], "theta_i_deg": [20.0, 40.0, 60.0], "theta_o_step_deg": 1.0}}
    with tempfile.TemporaryDirectory() as d:
        cfg = Path(d) / "c.toml"
        cfg.write_text(tomli_w.dumps(raw))
        with Bench.from_config(cfg) as bench:
            r = bench.capture(out=Path(d) / "out", progress=False)
        r.raise_for_status()
        rows = sorted(read_slice(r.slice_path).unix_time_s)
        return (rows[-1] - rows[0]) / (len(rows) - 1), len(rows)


def main() -> int:
    raw = tomllib.loads((REPO / "configs" / "simulated.toml").read_text())
    load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"{os.cpu_count()} CPUs, load average {load}; 500 new angle pairs, one READ of 4 repeats each")
    for name, material in (("blue plastic (ggx alpha 0.15)", raw["material"]), ("mirror (ggx alpha 1e-3)", MIRROR)):
        r = {**raw, "material": material}
        f_point, s_point = per_sample(r, point=True)
        f_phys, s_phys = per_sample(r, point=False)
        print(f"{name}: point instrument {s_point * 1e3:.2f} ms per sample, physical instrument "
              f"{s_phys * 1e3:.2f} ms per sample: +{(s_phys - s_point) * 1e3:.2f} ms per sample "
              f"(first call {f_phys * 1e3:.0f} ms)")
    r = {**raw, "material": MIRROR}
    near = near_peak_pairs()
    s_point, s_phys = per_sample(r, point=True, pairs=near)[1], per_sample(r, point=False, pairs=near)[1]
    print(f"mirror, only the {len(near)} pairs within 3 deg of the specular direction (the worst case): point "
          f"{s_point * 1e3:.2f} ms, physical {s_phys * 1e3:.2f} ms per sample: +{(s_phys - s_point) * 1e3:.2f} ms")
    per, n = capture_per_sample(raw)
    print(f"whole capture of configs/simulated.toml's material, {n} samples: {per * 1e3:.1f} ms per sample of wall "
          "time (acquisition, pseudo-terminals, simulator)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
