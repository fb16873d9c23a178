"""Draw docs/instrument-aperture-blur.png (docs/instrument.md, "Reconstruction that knows the instrument").

A mirror-like material (lambert 0.02 + ggx, specular 0.95) at theta_i = 30 deg, read through a detector cone of
1e-3 sr (half angle 1.02 deg), for alpha = 0.005 and 1e-3. Each panel shows, against theta_o - theta_i:

* f at the cone's centre (what a point detector would see, and what the simulator gave with aperture_samples = 1);
* the instrument's reading (reconstruction.instrument.response.instrument_average: f cos averaged over the cone);
* the samples of a 2 deg capture (the reading, 1 % noise), which fit is given with the instrument in their metadata;
* the lobe the fit recovers (f of the fitted material) and its reading through the same cone.

Prints the fitted alpha, its uncertainty or bound, and the specular amplitude for each panel.

Run: .venv/bin/python scripts/instrument_figures_reconstruction.py [--out docs]
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from reconstruction.core.geometry import inplane_to_dirs  # noqa: E402
from reconstruction.core.models import Colour, Lambert, Material, Microfacet  # noqa: E402
from reconstruction.core.slicedata import Slice  # noqa: E402
from reconstruction.instrument.response import Instrument, instrument_average  # noqa: E402
from reconstruction.methods.fit import reconstruct_fit  # noqa: E402

THETA_I = 30.0


def capture(alpha: float, inst: Instrument) -> tuple[Material, Slice]:
    """The material and a 2 deg capture at theta_i = 0, 20, 30, 40, 60 deg through ``inst`` (1 % noise)."""
    mat = Material("mirror-like", [Lambert(Colour(np.array([0.02]))),
                                   Microfacet(Colour(np.array([0.95])), alpha=alpha)])
    ti, to = np.meshgrid([0.0, 20.0, 30.0, 40.0, 60.0], np.arange(-80.0, 81.0, 2.0), indexing="ij")
    ti, to = ti.ravel(), to.ravel()
    keep = np.abs(to + ti) > 4
    ti, to = ti[keep], to[keep]
    v = instrument_average(mat, ti, to, inst)
    std = 0.01 * v + 1e-4
    meas = v + np.random.default_rng(3).normal(size=v.shape) * std
    return mat, Slice(ti, to, meas, ["value"], std, meta={"instrument": inst.to_meta()})


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(REPO / "out" / "figures"),
                    help="folder for the PNG (default: out/figures; --out docs updates the docs' figure)")
    args = ap.parse_args(argv)
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    inst = Instrument(1e-3)
    fig, axes = plt.subplots(1, 2, figsize=(11, 4.2), sharey=True)
    d = np.linspace(-4.0, 4.0, 1601)
    for ax, alpha in zip(axes, (0.005, 0.001), strict=True):
        mat, s = capture(alpha, inst)
        rec = reconstruct_fit(s)
        fitted = rec.material
        wi, wo = inplane_to_dirs(np.radians(THETA_I), np.radians(THETA_I + d))
        ax.semilogy(d, mat.eval(wi, wo)[:, 0], color="0.55", lw=4.0, alpha=0.6,
                    label="f at the cone's centre (truth)")
        ax.semilogy(d, instrument_average(mat, THETA_I, THETA_I + d, inst)[:, 0], color="C0", lw=2.0,
                    label="the instrument's reading")
        at = (s.theta_i_deg == THETA_I) & (np.abs(s.theta_o_deg - THETA_I) <= 4.0)
        ax.semilogy(s.theta_o_deg[at] - THETA_I, s.values[at, 0], "ko", ms=5, label="2 deg capture (1 % noise)")
        ax.semilogy(d, fitted.eval(wi, wo)[:, 0], "C3--", lw=1.2, label="fit's recovered lobe")
        ax.semilogy(d, instrument_average(fitted, THETA_I, THETA_I + d, inst)[:, 0], "C3:", lw=1.5,
                    label="its reading")
        rep = rec.report()
        p = next(q for q in rep["parameters"] if q["type"] in ("ggx", "beckmann"))
        lobe = next(n for n in rep["instrument"]["lobes"] if n["lobe"] == rep["parameters"].index(p))
        what = (f"fit: alpha = {p['alpha']:.4g} +- {p['alpha_std']:.2g}" if lobe["resolved"]
                else f"fit: alpha < {lobe['alpha_upper_bound']:.3g} (below resolution)")
        ax.set_title(f"ggx alpha = {alpha:g}, 1e-3 sr cone (half angle {inst.aperture_half_angle_deg:.2f} deg)\n"
                     f"{what}, specular {p['specular'][0]:.3f} (true 0.95)", fontsize=9)
        ax.set_xlabel("theta_o - theta_i (deg), theta_i = 30 deg")
        ax.axvspan(-inst.aperture_half_angle_deg, inst.aperture_half_angle_deg, color="C0", alpha=0.07)
        ax.set_ylim(1e-3, 5e5)
        ax.grid(True, which="major", alpha=0.3)
        print(f"alpha {alpha:g}: {rec.result.name}, {what}, specular {p['specular'][0]:.4f}"
              + (f"; note: {lobe['note']}" if "note" in lobe else ""))
    axes[0].set_ylabel("f_r or reading (1/sr)")
    axes[1].legend(fontsize=8, loc="upper right")
    fig.tight_layout()
    out = Path(args.out) / "instrument-aperture-blur.png"
    out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(out, dpi=110)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
