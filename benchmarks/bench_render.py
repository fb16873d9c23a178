"""Benchmark: the sphere renderer (reconstruction.core.render) on one core; prints seconds per image and its accuracy.

For a 128 x 128 image (the sphere filling the frame) of an analytic BRDF (lambert + GGX alpha 0.15 + Schlick
f0 0.04, the blue-plastic material) and of its MERL table (interpolated lookups), under the ``key`` and ``rim``
presets: the wall-clock and CPU seconds (median of ``--repeats``; a MERL table is rendered as a sparse product
whose operator is built at the first render of an image size and lighting: that first render is timed apart,
and so is the generic path, every pair looked up in the table, which gives the same values), and the
quadrature's error against a dense quadrature (2048 cosine-weighted + 7 x 512 GGX directions per pixel): RMS
and largest relative error over the pixels seen at up to 80 deg, and largest at 80-88 deg (the rim).

Run: .venv/bin/python benchmarks/bench_render.py [--size 128] [--repeats 3]
"""

from __future__ import annotations

import argparse
import statistics
import time

import numpy as np
from threadpoolctl import threadpool_limits

from reconstruction.core import merltable
from reconstruction.core.models import Material
from reconstruction.core.render import Lighting, Quadrature, SkyGround, render_sphere, view_angle_deg

MATERIAL = {"name": "blue-plastic", "lobes": [{"type": "lambert", "albedo": [0.05, 0.1, 0.4]},
                                              {"type": "ggx", "alpha": 0.15, "specular": 0.9, "f0": 0.04}]}
DENSE = Quadrature(n_cosine=2048, n_per_alpha=512, alphas=(0.003, 0.01, 0.03, 0.07, 0.15, 0.3, 0.6))


def timed(fn, repeats: int) -> tuple[float, float]:
    wall, cpu = [], []
    for _ in range(repeats):  # a few repeats
        t0, c0 = time.perf_counter(), time.process_time()
        fn()
        wall.append(time.perf_counter() - t0)
        cpu.append(time.process_time() - c0)
    return statistics.median(wall), statistics.median(cpu)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--size", type=int, default=128)
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--accuracy-size", type=int, default=64, help="image size of the accuracy check (dense: slow)")
    args = ap.parse_args()
    mat = Material.from_dict(MATERIAL)
    table_f = merltable.brdf_of(merltable.tabulate(mat.eval))
    print(f"default quadrature: {Quadrature().n_directions} directions per pixel")
    with threadpool_limits(limits=1):
        for preset in ("key", "rim"):
            t0 = time.perf_counter()
            fast = render_sphere(table_f, args.size, preset)
            first = time.perf_counter() - t0
            t0 = time.perf_counter()
            slow = render_sphere(lambda wi, wo: table_f(wi, wo), args.size, preset)
            generic = time.perf_counter() - t0
            diff = float(np.abs(fast - slow).max() / slow.max())
            print(f"MERL table {preset:4s} {args.size}x{args.size}: first render (builds the operator) {first:6.3f} s;"
                  f" generic path (a lookup per pair) {generic:6.3f} s; largest difference {diff:.1e} of the peak")
        for label, f in (("analytic", mat.eval), ("MERL table", table_f)):
            for preset in ("key", "rim"):
                wall, cpu = timed(lambda f=f, p=preset: render_sphere(f, args.size, p), args.repeats)
                print(f"{label:10s} {preset:4s} {args.size}x{args.size}: {wall:6.3f} s wall, {cpu:6.3f} s CPU "
                      f"(median of {args.repeats}, one core)")
        s = args.accuracy_size
        views = np.nan_to_num(view_angle_deg(s), nan=99.0)
        inner, rim = views <= 80.0, (views > 80.0) & (views <= 88.0)
        env = Lighting(SkyGround())
        ref = render_sphere(mat.eval, s, env, quadrature=DENSE)
        img = render_sphere(mat.eval, s, env)
        err = np.abs(img / np.where(ref > 0, ref, 1.0) - 1.0).max(axis=-1)
        print(f"environment quadrature vs dense ({s}x{s}, analytic): RMS {np.sqrt(np.mean(err[inner] ** 2)):.2%}, "
              f"max {err[inner].max():.2%} up to 80 deg; max {err[rim].max():.2%} at 80-88 deg")


if __name__ == "__main__":
    main()
