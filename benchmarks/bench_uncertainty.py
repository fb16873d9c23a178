"""Is the per-cell uncertainty honest? The prior's reconstruction and its sigma of ln f, leave-one-out on the real
materials of ../shared/realdata (nbrdf-merl and nbrdf-extra: 141), from 1, 2 and 3 in-plane slices.

For each material and capture the rest of the materials are the prior; over 20,000 direction pairs drawn uniformly
in solid angle (both angles <= 80 deg): the share with |ln(f_rec / f_true)| <= sigma and <= 2 sigma (target 60-76 %
and >= 90 %), the cosine-weighted L2 (cosl2) of the reconstruction and the one its sigma predicts (the expected
cosl2: sqrt(sum (f c sigma)^2 / sum (f c)^2) over the same pairs), and their rank correlation over materials.

``--no-prior``: what a user without a prior gets: the table ``auto`` writes without ``--prior`` and the sigma the
report gives it (the built-in analytic family's posterior with the two estimates' disagreement,
:func:`reconstruction.assess.uncertainty.sigma_grid`); no material is left out (none is in the analytic family).

Run: .venv/bin/python benchmarks/bench_uncertainty.py [--every N] [--captures 40 40/70 20/40/60] [--workers 2]
[--no-prior] [--scales 1,1.5,2]
(``--every 1``: all 141 materials, about 1 s per material and capture on one core.)
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.core.geometry import inplane_to_dirs  # noqa: E402
from reconstruction.core.models import Material  # noqa: E402
from reconstruction.core.slicedata import Slice  # noqa: E402
from reconstruction.methods import prior as P  # noqa: E402

DATA = ROOT.parent / "shared" / "realdata"
FOLDERS = (DATA / "nbrdf-merl", DATA / "nbrdf-extra")
STEP_DEG, BLIND_DEG, MAX_DEG = 2.0, 4.0, 80.0
_PS: P.PriorSet | None = None


def prior_set() -> P.PriorSet:
    """Both folders' materials as one prior (each folder tabulated once and cached)."""
    sets = [P.load_prior(f) for f in FOLDERS]
    return P.PriorSet("+".join(str(f) for f in FOLDERS), sum((s.names for s in sets), []),
                      np.concatenate([s.tables for s in sets]))


def material(name: str) -> Material:
    for f in FOLDERS:
        if (f / f"{name}_fc1.npy").is_file():
            return Material.from_dict({"name": name, "lobes": [{"type": "nbrdf", "path": str(f / name)}]})
    raise KeyError(name)


def bench_slice(mat: Material, incidences: tuple[float, ...]) -> Slice:
    """In-plane samples as a bench measures them: -80..80 deg every 2 deg, the blind spot left out."""
    to = np.arange(-MAX_DEG, MAX_DEG + 1e-9, STEP_DEG)
    a = np.concatenate([np.full(int(np.sum(np.abs(to + t) >= BLIND_DEG)), t) for t in incidences])
    b = np.concatenate([to[np.abs(to + t) >= BLIND_DEG] for t in incidences])
    f = mat.eval(*inplane_to_dirs(np.radians(a), np.radians(b)))
    return Slice(a, b, f, ["R", "G", "B"], np.zeros_like(f), source=mat.name)


def uniform_pairs(n: int = 20000, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    c0 = np.cos(np.radians(MAX_DEG))

    def cap() -> np.ndarray:
        ct = rng.uniform(c0, 1.0, n)
        ph = rng.uniform(0.0, 2 * np.pi, n)
        st = np.sqrt(1.0 - ct**2)
        return np.stack([st * np.cos(ph), st * np.sin(ph), ct], -1)

    return cap(), cap()


def one(args: tuple[str, tuple[float, ...], bool, tuple[float, ...]]) -> tuple[Any, ...]:
    global _PS
    warnings.simplefilter("ignore")
    name, incs, no_prior, scales = args
    mat = material(name)
    s = bench_slice(mat, incs)
    if no_prior:
        from threadpoolctl import threadpool_limits

        from reconstruction import pipeline
        from reconstruction.assess import uncertainty

        with threadpool_limits(1), np.errstate(all="ignore"):
            rec, _ = pipeline.reconstruct(s.sorted(), "auto")
            sigma = uncertainty.sigma_grid(rec, uncertainty.reference_posterior(s.sorted()))
    else:
        if _PS is None:
            _PS = prior_set()
        rec = P.reconstruct_prior(s, _PS, exclude=(name,))
        sigma = rec.sigma_ln.astype(np.float64)
    wi, wo = uniform_pairs()
    truth = np.asarray(mat.eval(wi, wo), dtype=np.float64)
    got = np.asarray(rec.eval(wi, wo), dtype=np.float64).reshape(truth.shape[0], -1)
    idx, w = P._dirs_weights(wi, wo)
    sd = np.einsum("nk,cnk->nc", w, sigma[:, idx])
    c = (wi[:, 2] * wo[:, 2])[:, None]
    cosl2 = float(np.sqrt(np.sum(((got - truth) * c) ** 2) / np.sum((truth * c) ** 2)))
    expected = float(np.sqrt(np.sum((got * c * sd) ** 2) / np.sum((got * c) ** 2)))
    ok = (truth > 1e-6) & (got > 0)
    err = np.abs(np.log(np.where(ok, got, 1.0) / np.where(ok, truth, 1.0)))
    in1 = float(np.mean((err <= sd)[ok]))
    in2 = float(np.mean((err <= 2 * sd)[ok]))
    scaled = [(float(np.mean((err <= s * sd)[ok])), float(np.mean((err <= 2 * s * sd)[ok]))) for s in scales]
    return name, "/".join(f"{t:g}" for t in incs), cosl2, expected, in1, in2, float(np.median(sd)), scaled


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--every", type=int, default=3, help="every N-th material of the 141 (1: all)")
    ap.add_argument("--captures", nargs="+", default=["40", "40/70", "20/40/60"])
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--no-prior", action="store_true",
                    help="auto without a prior and the report's sigma (the built-in analytic family)")
    ap.add_argument("--scales", default="", help="comma-separated factors: the shares within 1 and 2 sigma with "
                    "sigma multiplied by each (a calibration study), for all materials, those of nbrdf-merl and the "
                    "rest apart")
    args = ap.parse_args(argv)
    scales = tuple(float(x) for x in args.scales.split(",") if x)
    if not all(f.is_dir() for f in FOLDERS):
        print(f"bench_uncertainty: {DATA} not found (the real materials live beside the project)", file=sys.stderr)
        return 2
    # the prior's order (each folder's names sorted, folder after folder), without tabulating it
    names = [n for f in FOLDERS for n in sorted(p.name[: -len("_fc1.npy")] for p in f.glob("*_fc1.npy"))]
    names = names[:: args.every]
    caps = [tuple(float(x) for x in c.split("/")) for c in args.captures]
    t0 = time.perf_counter()
    jobs = [(n, c, args.no_prior, scales) for c in caps for n in names]
    with ProcessPoolExecutor(args.workers) as ex:
        rows = list(ex.map(one, jobs))
    print(f"{len(names)} materials x {len(caps)} captures, "
          + ("auto without a prior, sigma of the built-in analytic family, " if args.no_prior else
             "prior = the other materials of 141, ")
          + f"{time.perf_counter() - t0:.0f} s")
    print("| capture | within 1 sigma (pooled) | within 2 sigma | cosl2 median / worst | expected cosl2 median | "
          "rank corr. expected vs actual | median sigma |")
    print("|---|---|---|---|---|---|---|")
    from scipy.stats import spearmanr

    for c in args.captures:
        r = [x for x in rows if x[1] == c]
        a = np.array([x[2:7] for x in r])
        rho = spearmanr(a[:, 0], a[:, 1]).statistic
        print(f"| {c} deg | {a[:, 2].mean():.1%} | {a[:, 3].mean():.1%} | {np.median(a[:, 0]):.1%} / "
              f"{a[:, 0].max():.1%} ({r[int(np.argmax(a[:, 0]))][0]}) | {np.median(a[:, 1]):.1%} | {rho:.2f} | "
              f"{np.median(a[:, 4]):.3f} |")
    if scales:
        dev = {p.name[: -len("_fc1.npy")] for p in FOLDERS[0].glob("*_fc1.npy")}
        print("\nsigma multiplied by a factor: share within 1 / 2 sigma (pooled over materials), all | those of "
              "nbrdf-merl | the rest")
        for c in args.captures:
            r = [x for x in rows if x[1] == c]
            for k, s in enumerate(scales):
                parts = []
                for sel in (lambda n: True, lambda n: n in dev, lambda n: n not in dev):
                    v = np.array([x[7][k] for x in r if sel(x[0])])
                    parts.append(f"{v[:, 0].mean():.1%} / {v[:, 1].mean():.1%}" if v.size else "-")
                print(f"  {c:>9} deg x{s:<4g} " + " | ".join(parts))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
