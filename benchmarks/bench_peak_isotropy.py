"""Is a real material's specular peak isotropic about the mirror direction, as every reconstruction assumes?

An isotropic BRDF depends on (theta_h, theta_d, phi_d). Near the mirror direction a lobe that depends on theta_h
alone falls off alike in the plane of incidence and across it. In-plane slices see only the first, so every
method (and the prior, whose materials are tables of the same kind) extends the in-plane fall-off across the
plane. This benchmark reads each material of ``../shared/realdata`` (the neural BRDF itself, no table) at an
incidence of 40 deg: f at the mirror direction and at half vectors tilted by ``--tilt`` deg (0.25 by default,
an eighth of the benchmark's 2 deg step in theta_o) in the plane of incidence and across it, and prints the ratio
across / in-plane. A ratio far from 1 means that the slices' peak says nothing of the peak's energy: e.g. a peak
ten times narrower across the plane than in it holds about a tenth of the energy its in-plane profile implies.

Usage::

    .venv/bin/python benchmarks/bench_peak_isotropy.py [--data ../shared/realdata] [--tilt 0.25] [--theta-i 40]
"""

from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.core.models import Material  # noqa: E402

FOLDERS = ("nbrdf-merl", "nbrdf-extra")
#: a ratio across / in-plane outside [1 / FAR, FAR] is reported as anisotropic about the mirror direction
FAR = 2.0


def _names(folder: Path) -> list[str]:
    return sorted(p.name[: -len("_fc1.npy")] for p in folder.glob("*_fc1.npy"))


def peak_ratios(mat: Material, theta_i_deg: float, tilt_deg: float) -> tuple[float, float, float]:
    """(f at the mirror, f with the half vector tilted by ``tilt_deg`` in the plane of incidence, and across it),
    green channel (or the only one), 1/sr."""
    t = np.radians(theta_i_deg)
    wi = np.array([-np.sin(t), 0.0, np.cos(t)])
    a = np.radians(tilt_deg)
    hs = np.array([[0.0, 0.0, 1.0], [np.sin(a), 0.0, np.cos(a)], [0.0, np.sin(a), np.cos(a)]])
    wo = 2.0 * (hs @ wi)[:, None] * hs - wi
    f = np.asarray(mat.eval(np.broadcast_to(wi, wo.shape), wo), dtype=np.float64).reshape(3, -1)
    c = 1 if f.shape[1] > 1 else 0
    return float(f[0, c]), float(f[1, c]), float(f[2, c])


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "realdata"),
                    help="the real-data folder (nbrdf-merl/, nbrdf-extra/); default ../shared/realdata")
    ap.add_argument("--tilt", type=float, default=0.25, help="the half vector's tilt from the normal, deg")
    ap.add_argument("--theta-i", type=float, default=40.0, help="the incidence, deg (default 40)")
    args = ap.parse_args(argv)
    folders = [Path(args.data) / f for f in FOLDERS]
    if not any(f.is_dir() for f in folders):
        print(f"bench_peak_isotropy: no {' or '.join(FOLDERS)} in {args.data} (see ../shared/realdata/README.md)",
              file=sys.stderr)
        return 2
    warnings.simplefilter("ignore")
    rows = []
    for folder in folders:
        for n in _names(folder) if folder.is_dir() else []:
            mat = Material.from_dict({"name": n, "lobes": [{"type": "nbrdf", "path": str(folder / n)}]})
            with np.errstate(all="ignore"):
                peak, inp, across = peak_ratios(mat, args.theta_i, args.tilt)
            rows.append((across / inp if inp > 0 else np.nan, n, peak, inp, across))
    rows.sort(key=lambda r: (np.nan_to_num(abs(np.log(r[0])), nan=np.inf) if r[0] > 0 else np.inf), reverse=True)
    print(f"theta_i = {args.theta_i:g} deg, half vector tilted {args.tilt:g} deg from the mirror's; f in 1/sr "
          f"(green), the ratio across / in the plane of incidence")
    print(f"{'material':36s} {'f mirror':>10s} {'in-plane':>10s} {'across':>10s} {'ratio':>7s}")
    for ratio, n, peak, inp, across in rows:
        print(f"{n:36s} {peak:10.4g} {inp:10.4g} {across:10.4g} {ratio:7.3f}")
    r = np.array([x[0] for x in rows])
    far = int(np.sum((r > FAR) | (r < 1.0 / FAR)))
    print(f"{len(rows)} materials; ratio median {np.nanmedian(r):.3f}; outside [1/{FAR:g}, {FAR:g}]: {far} "
          f"(below 1/{FAR:g}, a peak narrower across the plane than in it: {int(np.sum(r < 1.0 / FAR))})")
    return 0


if __name__ == "__main__":
    sys.exit(main())
