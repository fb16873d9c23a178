"""Does the capture advice pick a good second slice? From a first slice at 40 deg of each real material (the other
materials of ../shared/realdata as the prior, leave-one-out), `--advise`'s ranking of the second incidence
against the oracle: for every candidate the second slice is measured (evaluated on the true material), the prior
reconstructs from both slices, and a sphere is rendered with it and with the truth (key and rim lighting, 64 px,
pixels seen within 80 deg); the actual PSNR of each candidate, the advised one's, the best one's (the oracle) and
the best single fixed choice's over the materials.

Run: .venv/bin/python benchmarks/bench_advice.py [--every N] [--step 10] [--workers 2]
(``--every 1``: all 141 materials; about 20 s per material with candidates every 10 deg on one core.)
"""

from __future__ import annotations

import argparse
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_uncertainty as B  # noqa: E402

from reconstruction.assess import advice  # noqa: E402
from reconstruction.core.metrics import image_psnr  # noqa: E402
from reconstruction.core.render import render_sphere, view_angle_mask  # noqa: E402
from reconstruction.methods import prior as P  # noqa: E402

SIZE = 64
_PS: P.PriorSet | None = None


def one(args: tuple[str, float]) -> tuple[str, dict[float, float], dict[float, float], float]:
    """(name, actual PSNR per candidate, expected PSNR per candidate, the advised candidate)."""
    global _PS
    warnings.simplefilter("ignore")
    name, step = args
    if _PS is None:
        _PS = B.prior_set()
    mat = B.material(name)
    first = B.bench_slice(mat, (40.0,)).sorted()
    ref = P.reconstruct_prior(first, _PS, exclude=(name,))
    lim = advice.BenchLimits()
    a = advice.advise(first, ref, lim)
    expected = {c["theta_i_deg"]: c["expected_psnr_db"] for c in a["candidates"]}
    mask = view_angle_mask(SIZE, 1.0, 80.0)
    truth = {k: render_sphere(mat.eval, SIZE, k) for k in ("key", "rim")}
    actual = {}
    for t in np.arange(0.0, 80.0 + 1e-9, step):
        if abs(t - 40.0) < 1e-9:
            continue
        both = advice.join_slices(first, B.bench_slice(mat, (float(t),))).sorted()
        rec = P.reconstruct_prior(both, _PS, exclude=(name,))
        mse = np.mean([10 ** (-image_psnr(render_sphere(rec.eval, SIZE, k), truth[k], mask) / 10) for k in truth])
        actual[float(t)] = float(-10 * np.log10(mse))
    advised, _ = advice.recommend({t: v for t, v in expected.items() if t in actual})  # as advise() does
    return name, actual, expected, advised


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--every", type=int, default=6, help="every N-th material of the 141 (1: all)")
    ap.add_argument("--offset", type=int, default=0, help="start at the OFFSET-th material (another subset)")
    ap.add_argument("--step", type=float, default=10.0, help="candidates every STEP deg (a multiple of 5)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", default=None, help="write every material's actual and expected PSNR per candidate")
    args = ap.parse_args(argv)
    if not all(f.is_dir() for f in B.FOLDERS):
        print(f"bench_advice: {B.DATA} not found (the real materials live beside the project)", file=sys.stderr)
        return 2
    names = B.prior_set().names[args.offset:: args.every]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as ex:
        rows = list(ex.map(one, [(n, args.step) for n in names]))
    if args.json:
        import json

        Path(args.json).write_text(json.dumps([{"material": n, "actual": a, "expected": e, "advised": d}
                                               for n, a, e, d in rows]))
    cands = sorted(rows[0][1])
    within, adv, oracle = [], [], []
    per_fixed = {t: [] for t in cands}
    for name, actual, _expected, advised in rows:
        best = max(actual.values())
        adv.append(actual[advised])
        oracle.append(best)
        within.append(best - actual[advised] <= 1.0)
        for t in cands:
            per_fixed[t].append(actual[t])
        print(f"{name:36s} advised {advised:4g} deg: {actual[advised]:5.1f} dB; best {max(actual, key=actual.get):4g} "
              f"deg: {best:5.1f} dB", flush=True)
    fixed = {t: float(np.median(v)) for t, v in per_fixed.items()}
    best_fixed = max(fixed, key=fixed.get)
    print(f"\n{len(rows)} materials, first slice 40 deg, candidates every {args.step:g} deg, "
          f"{time.perf_counter() - t0:.0f} s")
    print(f"advised within 1 dB of the oracle: {np.mean(within):.0%} of materials (target >= 75 %)")
    print(f"median PSNR: advised {np.median(adv):.2f} dB, oracle {np.median(oracle):.2f} dB, best fixed choice "
          f"({best_fixed:g} deg) {fixed[best_fixed]:.2f} dB")
    print("median PSNR per fixed second incidence: " + ", ".join(f"{t:g}: {v:.2f}" for t, v in fixed.items()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
