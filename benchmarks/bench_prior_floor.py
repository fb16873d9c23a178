"""How far can slices go? Floors of the prior's model on real materials, each chosen with the truth.

The ``prior`` method completes a material from a basis of other materials: a linear model in the mapped space
``log(f cos theta_i cos theta_o / s + EPS)`` on the reduced grid (:mod:`reconstruction.methods.prior`). This benchmark
fits that model, for every material of ``../shared/realdata/nbrdf-merl`` with a basis of the other 47
(leave-one-out), not to a slice's samples but to the material's **own exact values** on a set of grid cells,
with the number of components K and the ridge weight chosen per material **with the truth** (the lowest error
over a grid of K and weights). Each figure is therefore a floor: no slice of those cells, noiseless or not, can
do better with this model. The sets of cells:

* ``all``: every cell (how well the basis represents the material at all);
* ``theta_d<60``: every cell with theta_d < 60 deg, all azimuths (far more than in-plane slices up to 60 deg
  incidence see; the grazing specular peaks, theta_d >= 60 deg, are predicted);
* ``slice 40``, ``slices 20/40/60``, ``slices 40/70``: the cells the in-plane samples of those slices touch.

Error: rmse80 on the reduced grid (relative RMSE of f cos cos over the cells with both angles <= 80 deg; the
benchmark ``bench_real_materials.py`` judges on the MERL grid, the two agree to a few points). Usage::

    .venv/bin/python benchmarks/bench_prior_floor.py [--data ../shared/realdata] [--materials chrome,steel]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.formats.slicefile import Slice  # noqa: E402
from reconstruction.methods import prior as P  # noqa: E402

K_GRID = (3, 5, 10, 20, 30)
LAM_GRID = (0.01, 0.1, 1.0, 10.0, 100.0)
STEP_DEG, BLIND_DEG, MAX_DEG = 2.0, 4.0, 80.0
SLICE_CASES = {"slice 40": (40.0,), "slices 20/40/60": (20.0, 40.0, 60.0), "slices 40/70": (40.0, 70.0)}


def _slice(incidences: tuple[float, ...]) -> Slice:
    """The in-plane sample positions of the real-materials benchmark (values unused)."""
    to = np.arange(-MAX_DEG, MAX_DEG + 1e-9, STEP_DEG)
    a = np.concatenate([np.full(int(np.sum(np.abs(to + t) >= BLIND_DEG)), t) for t in incidences])
    b = np.concatenate([to[np.abs(to + t) >= BLIND_DEG] for t in incidences])
    return Slice(a, b, np.ones((a.size, 1)), ["value"])


def cell_sets() -> dict[str, np.ndarray]:
    """Boolean masks over the prior's training cells, one per case."""
    g = P._grid()
    tr = g["train"]
    nd = P.GRID[1]
    td = np.broadcast_to(((np.arange(nd) + 0.5) / nd * 90.0)[None, :, None], P.GRID).ravel()[tr]
    out = {"all": np.ones(int(tr.sum()), bool), "theta_d<60": td < 60.0}
    for name, incs in SLICE_CASES.items():
        idx, w, _ = P._design(_slice(incs))
        m = np.zeros(int(tr.sum()), bool)
        m[np.unique(idx[w > 0.05])] = True
        out[name] = m
    return out


def floors(ps: P.PriorSet, m: int, sets: dict[str, np.ndarray]) -> dict[str, float]:
    """rmse80 floor of material ``m`` of ``ps`` (basis: the others) for each set of observed cells."""
    g = P._grid()
    within = g["within"][g["train"]]
    idx, w, _ = P._design(_slice(SLICE_CASES["slice 40"]))  # the scale s: as the prior sets it from a 40 deg slice
    mu, comps, sig = ps.basis(idx, w, exclude=(ps.names[m],))
    fc = ps._fc()[3 * m:3 * m + 3].astype(np.float64)  # (3, M) f cos cos at the training cells
    scale = np.maximum(np.median(np.einsum("nj,cnj->cn", w, fc[:, idx]), axis=1), 1e-12)
    y = np.log(fc / scale[:, None] + P.EPS) - mu
    den = np.sqrt(np.sum(fc[:, within] ** 2))
    out = {}
    for name, obs in sets.items():
        best = np.inf
        for k in K_GRID:
            a = comps[:k, obs].T
            gram, rhs = a.T @ a, a.T @ y[:, obs].T
            for lam in LAM_GRID:
                coef = np.linalg.solve(gram + lam * np.diag(1.0 / sig[:k] ** 2), rhs)  # (k, 3)
                fh = np.maximum(np.exp(coef.T @ comps[:k] + mu) - P.EPS, 0.0) * scale[:, None]
                best = min(best, float(np.sqrt(np.sum((fh - fc)[:, within] ** 2)) / den))
        out[name] = best
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "realdata"),
                    help="the real-data folder (with nbrdf-merl/); default ../shared/realdata")
    ap.add_argument("--materials", help="comma-separated material names (default: all)")
    args = ap.parse_args(argv)
    folder = Path(args.data) / "nbrdf-merl"
    if not folder.is_dir():
        print(f"bench_prior_floor: {folder} not found (see ../shared/realdata/README.md)", file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    ps = P.load_prior(folder)
    want = [n.strip() for n in args.materials.split(",")] if args.materials else list(ps.names)
    missing = sorted(set(want) - set(ps.names))
    if missing or len(ps.names) < 3:
        print(f"bench_prior_floor: unknown material(s) {missing}" if missing else
              "bench_prior_floor: at least 3 materials are needed (a basis of 2 for each)", file=sys.stderr)
        return 2
    sets = cell_sets()
    rows = {}
    print(f"{'material':28s} " + " ".join(f"{k:>16s}" for k in sets))
    for n in want:
        rows[n] = floors(ps, ps.names.index(n), sets)
        print(f"{n:28s} " + " ".join(f"{v * 100:14.1f} %" for v in rows[n].values()), flush=True)
    print(f"floors of rmse80 with the prior's model (K and ridge weight chosen with the truth), {len(want)} "
          f"material(s), a basis of the other {len(ps.names) - 1} each:")
    for k in sets:
        v = np.array([r[k] for r in rows.values()]) * 100
        print(f"  {k:16s} median {np.median(v):5.1f} %, mean {v.mean():5.1f} %, worst {v.max():6.1f} % "
              f"({want[int(np.argmax(v))]}); > 15 %: {int(np.sum(v > 15))}, > 50 %: {int(np.sum(v > 50))}")
    print(f"{time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())
