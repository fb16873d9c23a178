"""Benchmark: the energy of a lobe narrower than the MERL cells in the default table, and what keeping it costs.

For lambert + ggx materials from a mirror (alpha 1e-4) to a glossy lobe (1e-2), the table pipeline.tabulate writes
for the exact BRDF (cell averages over theta_h where the lobe is sub-cell, then reconstruction.core.sharprows), read
both
ways: interpolating between bin centres (the plausibility check, previews) and snapping to cells (the MERL reference
reader, renderers). Prints the exact albedo, each reader's albedo before and after the renormalisation at
theta_i = 0 / 60 / 80 / 85 deg, and the seconds of the renormalisation (the readers' matrices come from the disk
cache after their first build, printed apart).

Run: .venv/bin/python benchmarks/bench_sharp_energy.py
"""

from __future__ import annotations

import os
import time

import numpy as np

from reconstruction.core import merltable, sharprows
from reconstruction.core.metrics import halfvector_albedo
from reconstruction.core.models import Material

CASES = [(0.0, 1e-4, 1.0), (0.02, 1e-3, 0.95), (0.0, 1e-3, 1.0), (0.1, 5e-3, 0.9), (0.05, 1e-2, 0.95)]
THETA_I_DEG = np.array([0.0, 60.0, 80.0, 85.0])


def _read(table: np.ndarray, interpolate: bool) -> np.ndarray:
    look = lambda wi, wo: np.nan_to_num(merltable.lookup(table, wi, wo, interpolate=interpolate))  # noqa: E731
    return halfvector_albedo(look, np.radians(THETA_I_DEG))[:, 0]


def main() -> None:
    load = " / ".join(f"{x:.1f}" for x in os.getloadavg())
    print(f"{os.cpu_count()} CPUs, load average {load}; albedo at theta_i = {THETA_I_DEG.tolist()} deg")
    print(f"{'material':<32} {'reader':<14} {'before':<28} {'after':<28} {'seconds':>8}")
    for lam, alpha, ks in CASES:
        mat = Material.from_dict({"name": "m", "lobes": [{"type": "lambert", "albedo": lam},
                                                         {"type": "ggx", "alpha": alpha, "specular": ks}]})
        sharp = 5.0 * alpha  # the rows fit and microfacet average for such a lobe
        table, _ = merltable.average_theta_h_cells(mat.eval, merltable.tabulate(mat.eval), sharp, n=8)
        t0 = time.perf_counter()
        sharprows._readers(sharprows.sharp_rows(sharp))  # built once per machine, then read from the cache
        build = time.perf_counter() - t0
        t0 = time.perf_counter()
        after, _ = sharprows.renormalise(mat.eval, table, sharp)
        secs = time.perf_counter() - t0
        exact = halfvector_albedo(mat.eval, np.radians(THETA_I_DEG))[:, 0]
        name = f"lambert {lam:g} + ggx {alpha:g} x {ks:g}"
        print(f"{name:<32} {'exact':<14} {np.array2string(exact, precision=3):<28}")
        for label, interp in (("interpolating", True), ("snapping", False)):
            print(f"{'':<32} {label:<14} {np.array2string(_read(table, interp), precision=3):<28} "
                  f"{np.array2string(_read(after, interp), precision=3):<28} {secs if interp else build:>8.3f}")
    print("seconds: the renormalisation (interpolating row), the readers' matrices' lookup or first build (snapping)")


if __name__ == "__main__":
    main()
