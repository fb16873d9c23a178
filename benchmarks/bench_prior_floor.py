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
benchmark ``bench_real_materials.py`` judges on the MERL grid, the two agree to a few points).

``--image`` judges the floors as ``bench_real_materials.py`` judges a reconstruction: every material of
``nbrdf-merl`` and ``nbrdf-extra`` (141), a basis of the other 140, and per set of cells the PSNR of the
tone-mapped renders (key and rim lighting, their mean) of the floor's MERL table against the truth's (the
benchmark's cached truth tables with ``--truth-cache``, else the neural BRDF tabulated). K and the ridge weight are
chosen with the truth by the PSNR of 64-pixel renders (K 5, 10, 20, 30; weights 0.1, 1, 10), the chosen one's
figure from 128-pixel renders: a floor by the image (no slice of those cells does better with this model, up to
the two render sizes). About 55 s per material and worker (``--every 3``: 47 materials in about 25 min on 2
cores). Usage::

    .venv/bin/python benchmarks/bench_prior_floor.py [--data ../shared/realdata] [--materials chrome,steel]
    .venv/bin/python benchmarks/bench_prior_floor.py --image [--truth-cache out/real-materials-cache] [--every 3]
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.core.slicedata import Slice  # noqa: E402
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


def _setup(ps: P.PriorSet, m: int) -> tuple[np.ndarray, ...]:
    """Material ``m`` of ``ps`` and the basis of the others: (mean, components, standard deviations, its f cos cos
    (3, M) at the training cells, its scale s (3,), its mapped values y (3, M))."""
    idx, w, _ = P._design(_slice(SLICE_CASES["slice 40"]))  # the scale s: as the prior sets it from a 40 deg slice
    mu, comps, sig = ps.basis(idx, w, exclude=(ps.names[m],))
    fc = ps._fc()[3 * m:3 * m + 3].astype(np.float64)
    scale = np.maximum(np.median(np.einsum("nj,cnj->cn", w, fc[:, idx]), axis=1), 1e-12)
    return mu, comps, sig, fc, scale, np.log(fc / scale[:, None] + P.EPS) - mu


def _fits(setup: tuple[np.ndarray, ...], obs: np.ndarray, ks: tuple[int, ...], lams: tuple[float, ...]
          ) -> Iterator[np.ndarray]:
    """The material of :func:`_setup` fitted to its own exact values at the training cells ``obs``, for every K of
    ``ks`` and ridge weight of ``lams``: each fit's f cos cos (3, M), one at a time."""
    mu, comps, sig, _, scale, y = setup
    for k in ks:
        a = comps[:k, obs].T
        gram, rhs = a.T @ a, a.T @ y[:, obs].T
        for lam in lams:
            coef = np.linalg.solve(gram + lam * np.diag(1.0 / sig[:k] ** 2), rhs)  # (k, 3)
            yield np.maximum(np.exp(coef.T @ comps[:k] + mu) - P.EPS, 0.0) * scale[:, None]


def floors(ps: P.PriorSet, m: int, sets: dict[str, np.ndarray]) -> dict[str, float]:
    """rmse80 floor of material ``m`` of ``ps`` (basis: the others) for each set of observed cells."""
    g = P._grid()
    within = g["within"][g["train"]]
    setup = _setup(ps, m)
    fc = setup[3]
    den = np.sqrt(np.sum(fc[:, within] ** 2))
    return {name: min(float(np.sqrt(np.sum((fh - fc)[:, within] ** 2)) / den)
                      for fh in _fits(setup, obs, K_GRID, LAM_GRID)) for name, obs in sets.items()}


IMAGE_SETS = ("all", "slice 40", "slices 40/70", "slices 20/40/60")
IMAGE_K, IMAGE_LAM = (5, 10, 20, 30), (0.1, 1.0, 10.0)  # --image: the grid its renders choose from


def _candidates(ps: P.PriorSet, m: int, sets: dict[str, np.ndarray]) -> dict[str, list[np.ndarray]]:
    """Per set of cells, the floor's reduced-grid f_r (3, n_cells) for every K of :data:`IMAGE_K` and ridge weight
    of :data:`IMAGE_LAM`, fitted to the material's own values at those cells."""
    g = P._grid()
    setup = _setup(ps, m)
    out: dict[str, list[np.ndarray]] = {}
    for name in IMAGE_SETS:
        out[name] = []
        for fh in _fits(setup, sets[name], IMAGE_K, IMAGE_LAM):
            f = np.zeros((3, g["cos"].size))
            f[:, g["train"]] = fh / g["cos"][g["train"]]
            out[name].append(np.where(g["cos"] > 0, P._extend(f), 0.0))
    return out


def _image_floor(job: tuple[str, str, str | None, int]) -> dict[str, object]:
    """Worker: one material's image floors (PSNR, dB) per set of cells: K and the ridge weight chosen by the PSNR
    of renders of half the size, the chosen one's figure from renders of the size (128: the other benchmark's)."""
    import warnings

    from threadpoolctl import threadpool_limits

    from reconstruction.core import merlgrid, merltable
    from reconstruction.core.models import Material
    from reconstruction.report import compare as cmp

    warnings.simplefilter("ignore")
    name, folders, cache, size = job
    with threadpool_limits(1), np.errstate(all="ignore"):
        ps = P.load_prior(folders.split(","))
        cached = Path(cache) / f"{name}.npy" if cache else None
        if cached is not None and cached.is_file():
            truth = np.load(cached).astype(np.float64)
        else:
            folder = next(f for f in folders.split(",") if (Path(f) / f"{name}_fc1.npy").is_file())
            mat = Material.from_dict({"name": name, "lobes": [{"type": "nbrdf", "path": str(Path(folder) / name)}]})
            truth = merltable.tabulate(mat.eval)
        valid = merlgrid.valid_mask()[None]
        truth = np.where(valid, truth, np.nan)
        tb = cmp.Brdf(name, "merl", merltable.brdf_of(truth), truth)
        small, full = cmp.reference(tb, max(size // 2, 8), n_pairs=1000), cmp.reference(tb, size, n_pairs=1000)

        def psnr(f: np.ndarray, ref: cmp.Reference) -> float:
            t = np.where(valid, P.PriorReconstruction(["R", "G", "B"], f, {}).table(), np.nan)
            return float(cmp.image_metrics(cmp.render_images(cmp.Brdf("floor", "merl", merltable.brdf_of(t), t),
                                                             ref.size), ref.images, ref.size)["psnr_db"])

        out: dict[str, object] = {"material": name}
        for set_name, tables in _candidates(ps, ps.names.index(name), cell_sets()).items():
            best = max(tables, key=lambda f: psnr(f, small))
            out[set_name] = psnr(best, full)
        return out


def image_main(args: argparse.Namespace) -> int:
    """``--image``: the floors' PSNR over the 141 materials (see the module docstring)."""
    import multiprocessing

    folders = [Path(args.data) / "nbrdf-merl", Path(args.data) / "nbrdf-extra"]
    if not all(f.is_dir() for f in folders):
        print(f"bench_prior_floor: {folders[0]} or {folders[1]} not found (see ../shared/realdata/README.md)",
              file=sys.stderr)
        return 2
    t0 = time.perf_counter()
    ps = P.load_prior([str(f) for f in folders])  # built (or read from the cache) once, before the workers
    want = [n.strip() for n in args.materials.split(",")] if args.materials else sorted(ps.names)
    missing = sorted(set(want) - set(ps.names))
    if missing:
        print(f"bench_prior_floor: unknown material(s) {missing}", file=sys.stderr)
        return 2
    want = want[:: max(1, args.every)]
    jobs = [(n, ",".join(str(f) for f in folders), args.truth_cache, args.size) for n in want]
    rows = []
    print(f"{'material':34s} " + " ".join(f"{k:>16s}" for k in IMAGE_SETS))
    pool = multiprocessing.get_context("fork").Pool(args.workers) if args.workers > 1 else None
    try:
        for r in pool.imap_unordered(_image_floor, jobs) if pool is not None else map(_image_floor, jobs):
            rows.append(r)
            print(f"{r['material']:34s} " + " ".join(f"{r[k]:13.1f} dB" for k in IMAGE_SETS), flush=True)
    finally:
        if pool is not None:
            pool.close()
    print(f"floors of the image PSNR with the prior's model (K and ridge weight chosen with the truth), "
          f"{len(rows)} material(s), a basis of the other {len(ps.names) - 1} each:")
    for k in IMAGE_SETS:
        v = np.array([r[k] for r in rows], dtype=np.float64)
        print(f"  {k:16s} median {np.median(v):5.1f} dB, mean {v.mean():5.1f} dB, worst {v.min():5.1f} dB; "
              f">= 38 dB: {int(np.sum(v >= 38))}, >= 40 dB: {int(np.sum(v >= 40))}, >= 41 dB: {int(np.sum(v >= 41))}")
    print(f"{time.perf_counter() - t0:.0f} s")
    return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "realdata"),
                    help="the real-data folder (with nbrdf-merl/); default ../shared/realdata")
    ap.add_argument("--materials", help="comma-separated material names (default: all)")
    ap.add_argument("--image", action="store_true",
                    help="judge the floors by the rendered image (PSNR), over nbrdf-merl and nbrdf-extra (141)")
    ap.add_argument("--truth-cache", default=None,
                    help="with --image: the truth tables bench_real_materials.py cached (NAME.npy), e.g. "
                         "out/real-materials-cache; else each neural BRDF is tabulated")
    ap.add_argument("--workers", type=int, default=2, help="with --image: worker processes (default 2)")
    ap.add_argument("--size", type=int, default=128,
                    help="with --image: the renders' size in pixels (default 128, as bench_real_materials.py)")
    ap.add_argument("--every", type=int, default=1,
                    help="with --image: every N-th material in name order (default 1: all; 3 takes about 25 min)")
    args = ap.parse_args(argv)
    if args.image:
        return image_main(args)
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
