"""Benchmark: a real hemispherical Zemax file reconstructed from all its points, and incidences held out; the Zemax
and RGL round trips (docs/formats.md).

Prints:

* the real file ``../shared/realdata/zemax/speos-converted-550nm.bsdf`` (skipped when absent): ``gonio-reconstruct
  FILE --method auto`` in-process (read to written table, and the process end to end), the table compared with
  every point of the file above the horizon (solid-angle weighted relative RMSE of f cos theta_i cos theta_o, the
  solid angle of each grid point about the specular direction, sin r dr da), per incidence and pooled; every method
  from all points the same way; each incidence held out (auto on the points of the others, then predicting the
  held-out points); and a bound: the same grid as ``bivariate``'s fitted without the reciprocity fold (phi_d in
  0-180 deg), i.e. what a non-reciprocal table could reproduce;
* the Zemax round trip: ``--zemax`` of a ``fit`` of three synthetic demo slices, read back with ``--method fit``:
  median relative difference of the two MERL tables over 20,000 random direction pairs within 80 deg;
* what the default Zemax grid keeps: the file's values interpolated (reconstruction.formats.brdffile.load_brdf)
  against lambert 0.1 + ggx(F) lobes of alpha 0.3, 0.15, 0.05 (median relative difference and relative RMSE of
  f cos cos over the random pairs);
* RGL read-back: ``--rgl`` output of the same fit read back (load_brdf, Mitsuba's eval) against the MERL table.

Run: ``.venv/bin/python benchmarks/bench_zemax_real.py``
"""

from __future__ import annotations

import math
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction import pipeline  # noqa: E402
from reconstruction.core import merltable  # noqa: E402
from reconstruction.core.models import Colour, Lambert, Material, Microfacet  # noqa: E402
from reconstruction.core.samples import PointFolds, out_of_plane  # noqa: E402
from reconstruction.formats import merl, zemax  # noqa: E402
from reconstruction.formats.brdffile import load_brdf  # noqa: E402
from reconstruction.formats.slicefile import write_slice  # noqa: E402
from reconstruction.methods import Options  # noqa: E402
from reconstruction.synthetic import synthetic_slice  # noqa: E402

REAL = ROOT.parent / "shared" / "realdata" / "zemax" / "speos-converted-550nm.bsdf"
CLI = str(ROOT / ".venv" / "bin" / "gonio-reconstruct")


def grid_points(z: zemax.ZemaxBSDF):
    """(wi, wo, f (I, A, N) grey or luminance, solid-angle weights, incidence index, above-horizon mask)."""
    v, _ = z.rgb_values()
    f = v.mean(axis=0)
    inc, az, rad = z.incidence_deg, z.azimuth_deg, z.radial_deg
    wi, wo = zemax.scatter_directions(inc[:, None, None], az[None, :, None], rad[None, None, :])
    w = zemax._trapezoid(np.radians(az))[:, None] * (zemax._trapezoid(np.radians(rad)) * np.sin(np.radians(rad)))
    w = np.broadcast_to(w[None], f.shape)
    k = np.broadcast_to(np.arange(inc.size)[:, None, None], f.shape)
    up = (wo[..., 2] > math.cos(math.radians(89.0))) & (inc[:, None, None] < 90)
    return wi, wo, f, w, k, up


def weighted_rmse(pred, f, wi, wo, w) -> float:
    c = wi[..., 2] * wo[..., 2]
    return math.sqrt(float(np.sum(w * ((pred - f) * c) ** 2)) / float(np.sum(w * (f * c) ** 2)))


def against_points(fn, z, mask=None) -> tuple[float, list[float]]:
    """(pooled error, per incidence) of the BRDF ``fn`` against the file's points (module docstring)."""
    wi, wo, f, w, k, up = grid_points(z)
    m = up if mask is None else up & mask
    pred = np.asarray(fn(wi[m], wo[m])).mean(axis=1)
    per = [weighted_rmse(pred[k[m] == j], f[m][k[m] == j], wi[m][k[m] == j], wo[m][k[m] == j], w[m][k[m] == j])
           for j in np.unique(k[m])]
    return weighted_rmse(pred, f[m], wi[m], wo[m], w[m]), per


def real_file() -> None:
    t0 = time.perf_counter()
    s, notes, z = zemax.load_input(REAL)
    t_read = time.perf_counter() - t0
    pts = s.points
    print(f"{REAL.name}: {REAL.stat().st_size / 1e6:.1f} MB, incidences {z.incidence_deg.tolist()} deg, "
          f"{z.azimuth_deg.size} azimuths x {z.radial_deg.size} radial angles, {len(pts):,} points above the "
          f"horizon ({int(out_of_plane(pts).sum()):,} out of the plane of incidence); read {t_read:.2f} s")
    t0 = time.perf_counter()
    rec, choice = pipeline.reconstruct(s, "auto", Options())
    table = pipeline.tabulate(rec)
    t_rec = time.perf_counter() - t0
    pooled, per = against_points(merltable.brdf_of(table), z)
    print(f"  auto from all points: {rec.method} (held-out: {choice['cross_validation']['scheme']}), read + "
          f"reconstruct + tabulate {t_read + t_rec:.2f} s; the table against every point: {pooled:.1%} (per "
          f"incidence {', '.join(f'{x:g}: {e:.1%}' for x, e in zip(z.incidence_deg, per, strict=True))})")
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        subprocess.run([CLI, str(REAL), "--method", "auto", "--out", f"{tmp}/t.binary", "--quiet"], check=True)
        print(f"  gonio-reconstruct FILE --method auto --out t.binary, process start to exit: "
              f"{time.perf_counter() - t0:.2f} s (target < 3 s)")
    for method in ("bivariate", "fit", "microfacet", "revolve"):
        r, _ = pipeline.reconstruct(s, method, Options())
        pooled, per = against_points(merltable.brdf_of(pipeline.tabulate(r)), z)
        print(f"  {method:10s} from all points, its table against every point: {pooled:.1%} "
              f"({', '.join(f'{e:.1%}' for e in per)})")
    from reconstruction.methods import scattered  # the reciprocity bound: the same grid, phi_d over 0-180 deg

    coords = scattered._coords
    scattered._coords = lambda th, td, pd, shape: coords(th, td, np.minimum(np.mod(pd, 2 * np.pi), 2 * np.pi - np.mod(
        pd, 2 * np.pi)) / 2.0, shape)
    try:
        free = scattered.reconstruct_scattered(pts.take(np.random.default_rng(0).choice(len(pts), 10_000, False)))
        pooled, _ = against_points(free.eval, z)
    finally:
        scattered._coords = coords
    print(f"  bound: the same grid without the reciprocity fold (phi_d 0-180 deg) reproduces the points to "
          f"{pooled:.1%}; the file is not reciprocal, which a reciprocal table (MERL) cannot follow")
    folds = PointFolds.of(pts)
    for j, t in enumerate(z.incidence_deg):
        if t <= 0:
            continue
        held = np.isclose(folds.theta_i_deg, t)
        train = folds.take(~held)
        r, ch = pipeline.reconstruct(train, "auto", Options())
        pooled, _ = against_points(r.eval, z, grid_points(z)[4] == j)
        print(f"  incidence {t:g} deg held out: auto ({r.method}) from the other incidences predicts it to "
              f"{pooled:.1%} (target <= 10 %)")


def imaging_sphere_speed() -> None:
    """A file shaped as the imaging-sphere measurement of issue 25 (13 incidences 15-75 deg, 19 azimuths 0-360 x 11
    radial angles 0-50 deg; a synthetic Oren-Nayar + ggx material): auto from all its points, timed."""
    from reconstruction.core.models import OrenNayar

    mat = Material("rough", [OrenNayar(colour=Colour(np.array([0.3])), sigma_deg=30.0),
                             Microfacet(colour=Colour(np.array([0.5])), alpha=0.2, f0=0.04)])
    inc, az, rad = np.arange(15.0, 76.0, 5.0), np.arange(0.0, 361.0, 20.0), np.arange(0.0, 51.0, 5.0)
    v = zemax.tabulate(mat.eval, inc, az, rad)
    z = zemax.ZemaxBSDF("Asymmetrical", "Monochrome", "BRDF", np.zeros(1), inc, az, rad, v[:, None],
                        np.zeros((1, 1, inc.size)), ["value"])
    with tempfile.TemporaryDirectory() as tmp:
        lines = ["Source  Measured", "Symmetry  Asymmetrical", "SpectralContent  Monochrome", "ScatterType  BRDF",
                 "SampleRotation  1", "0"]
        for key, a in (("AngleOfIncidence", inc), ("ScatterAzimuth", az), ("ScatterRadial", rad)):
            lines += [f"{key}  {a.size}", "\t".join(f"{x:g}" for x in a)]
        lines += ["Monochrome", "DataBegin"]
        for k in range(inc.size):
            lines.append("TIS 0.5")
            lines += ["\t".join(f"{x:.6e}" for x in row) for row in v[0, k]]
        Path(f"{tmp}/sphere.bsdf").write_text("\n".join(lines + ["DataEnd"]) + "\n")
        t0 = time.perf_counter()
        s, _, _ = zemax.load_input(f"{tmp}/sphere.bsdf")
        rec, _ = pipeline.reconstruct(s, "auto", Options())
        table = pipeline.tabulate(rec)
        t_in = time.perf_counter() - t0
        t0 = time.perf_counter()
        subprocess.run([CLI, f"{tmp}/sphere.bsdf", "--method", "auto", "--out", f"{tmp}/t.binary", "--quiet"],
                       check=True)
        t_cli = time.perf_counter() - t0
    pooled, _ = against_points(merltable.brdf_of(table), z)
    print(f"An imaging-sphere-shaped file ({inc.size} incidences x {az.size} azimuths x {rad.size} radial angles, "
          f"{len(s.points):,} points; synthetic Oren-Nayar + ggx): auto ({rec.method}) read + reconstruct + "
          f"tabulate {t_in:.2f} s in-process, gonio-reconstruct end to end {t_cli:.2f} s (target < 3 s); the table "
          f"against every point {pooled:.2%}")


def round_trips() -> None:
    mat = Material.from_toml(ROOT / "configs" / "simulated.toml")
    rng = np.random.default_rng(7)
    ct = rng.uniform(math.cos(math.radians(80)), 1.0, (2, 20_000))
    ph = rng.uniform(0, 2 * np.pi, (2, 20_000))
    d = np.stack([np.sqrt(1 - ct ** 2) * np.cos(ph), np.sqrt(1 - ct ** 2) * np.sin(ph), ct], -1)
    wi, wo = d[0], d[1]
    with tempfile.TemporaryDirectory() as tmp:
        sl = synthetic_slice(mat, [20.0, 40.0, 60.0], noise=0.0)
        write_slice(f"{tmp}/s.csv", sl)
        subprocess.run([CLI, f"{tmp}/s.csv", "--method", "fit", "--out", f"{tmp}/a.binary", "--zemax", f"{tmp}/z.bsdf",
                        "--rgl", f"{tmp}/r.bsdf", "--quiet"], check=True)
        subprocess.run([CLI, f"{tmp}/z.bsdf", "--method", "fit", "--out", f"{tmp}/b.binary", "--quiet"], check=True)
        a, b = merltable.brdf_of(merl.read(f"{tmp}/a.binary")), merltable.brdf_of(merl.read(f"{tmp}/b.binary"))
        va, vb = a(wi, wo), b(wi, wo)
        print(f"Zemax round trip (fit of 3 synthetic demo slices -> --zemax, default grid "
              f"{Path(f'{tmp}/z.bsdf').stat().st_size / 1e6:.2f} MB -> gonio-reconstruct z.bsdf --method fit): "
              f"median relative difference of the tables {np.median(np.abs(vb - va) / va):.2%} (target <= 2 %)")
        rgl = load_brdf(f"{tmp}/r.bsdf")(wi, wo)
        print(f"RGL read-back of the same fit's --rgl output (Mitsuba's eval) against its MERL table: median "
              f"{np.median(np.abs(rgl - va) / va):.2%} (target <= 1 %)")
        print("What the default Zemax grid keeps (its values interpolated by a reader against the lobe):")
        c = wi[:, 2] * wo[:, 2]
        for alpha in (0.3, 0.15, 0.05):
            m = Material("m", [Lambert(colour=Colour(np.array([0.1]))),
                               Microfacet(colour=Colour(np.array([1.0])), alpha=alpha, f0=0.04)])
            zemax.write(f"{tmp}/g.bsdf", m.eval, ["value"])
            g, want = load_brdf(f"{tmp}/g.bsdf")(wi, wo)[:, 0], m.eval(wi, wo)[:, 0]
            rmse = math.sqrt(np.sum(((g - want) * c) ** 2) / np.sum((want * c) ** 2))
            print(f"  lambert 0.1 + ggx(F) alpha {alpha:g}: median {np.median(np.abs(g - want) / want):.2%}, "
                  f"relative RMSE of f cos cos {rmse:.1%}")


def main() -> None:
    if REAL.exists():
        real_file()
    else:
        print(f"{REAL}: absent (../shared/realdata); the real file's figures are skipped")
    imaging_sphere_speed()
    round_trips()


if __name__ == "__main__":
    main()
