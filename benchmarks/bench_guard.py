"""auto's conservative bound and its expected errors, on the real materials (issue 24 sections 3 and 5).

For each material (leave-one-out: the other materials of ../shared/realdata are the prior) and capture, auto with
the prior reconstructs the in-plane slices as bench_real_materials.py samples them; the table is judged against
the truth's own MERL table as a renderer sees it (key and rim lighting, 64 px) with and without the bound
(``pipeline.bound_where_unmeasured``: the prior posterior's median x exp(k sigma) where no sample rests), for k = 1
and 2, and beside the report's expected linear image error. Printed: per variant the median and worst linear image
error, how many materials are above 50 %, the median and worst PSNR, the median cosl2; and the rank correlation
(Spearman) of the expected and the actual linear image error across materials.

Run: .venv/bin/python benchmarks/bench_guard.py [--every 3] [--slices 1] [--workers 2]
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
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_real_materials as B  # noqa: E402

from reconstruction import pipeline  # noqa: E402
from reconstruction.assess import guard, uncertainty  # noqa: E402
from reconstruction.core import merltable  # noqa: E402
from reconstruction.core.models import Material  # noqa: E402
from reconstruction.methods import Options  # noqa: E402
from reconstruction.report import compare as cmp  # noqa: E402

DATA = ROOT.parent / "shared" / "realdata"
FOLDERS = (DATA / "nbrdf-merl", DATA / "nbrdf-extra")
SIZE = 64


#: the bounds' k (sigmas above the reference posterior's median) each variant is judged with
KS = (1.0, 2.0)
KS_NO_PRIOR = (1.0, 2.0, 3.0)


def one(job: tuple[str, str, bool]) -> dict[str, Any]:
    """One material and capture: the figures of every variant and the expected linear image error; with
    ``no_prior`` (the job's third item) auto without a prior, bounded by the built-in analytic family's posterior."""
    warnings.simplefilter("ignore")
    from threadpoolctl import threadpool_limits

    name, mode, no_prior = job
    folder = next(f for f in FOLDERS if (f / f"{name}_fc1.npy").is_file())
    with threadpool_limits(1), np.errstate(all="ignore"):
        mat = Material.from_dict({"name": name, "lobes": [{"type": "nbrdf", "path": str(folder / name)}]})
        truth = B._as_read(merltable.tabulate(mat.eval))
        ref_img = cmp.reference(cmp.Brdf(name, "merl", merltable.brdf_of(truth), truth), SIZE)
        s = B.slices_of(mat, B.incidences_of(mode)).sorted()
        prior = "" if no_prior else ":".join(str(f) for f in FOLDERS)
        opts = Options(prior=prior or None, prior_exclude=(name,))
        rec, choice = pipeline.reconstruct(s, "auto", opts)
        table = pipeline.tabulate(rec)
        ref = uncertainty.reference_for(rec, s, prior or None, (name,))
        written, _, _, _ = pipeline.bound_where_unmeasured(rec, table, s, opts, ref)  # as gonio-reconstruct writes
        _, section, *_ = uncertainty.assess_table(written, s, prior or None, (name,), ref)
        out: dict[str, Any] = {"material": name, "database": B.database_of(str(folder), name), "mode": mode,
                               "used": choice["used"], "expected_linear": section["expected_linear_image_error"]}

        def judge(t: np.ndarray, key: str) -> None:
            a = cmp.Brdf(key, "merl", merltable.brdf_of(B._as_read(t)), B._as_read(t))
            r = cmp.judge(a, ref_img, with_rmse80=False)
            out[key] = (r["image"]["relative_rmse"], r["image"]["psnr_db"], r["cosl2"])

        judge(table, "unbounded")
        for k in KS_NO_PRIOR if no_prior else KS:
            _, bounded, info = guard.conservative(rec, table, s, ref, k)
            judge(bounded, f"bound k={k:g}")
            out[f"energy k={k:g}"] = info["energy_removed"]
    return out


def main(argv: list[str] | None = None) -> int:
    from scipy.stats import spearmanr

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--every", type=int, default=3, help="every N-th material of the 141 (1: all)")
    ap.add_argument("--slices", default="1", help="cases as in bench_real_materials.py: 1 (40 deg), 2, 3")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--json", help="write every material's figures to this file")
    ap.add_argument("--no-prior", action="store_true",
                    help="auto without a prior, bounded by the built-in analytic family (k = 1, 2, 3)")
    args = ap.parse_args(argv)
    if not all(f.is_dir() for f in FOLDERS):
        print(f"bench_guard: {DATA} not found (the real materials live beside the project)", file=sys.stderr)
        return 2
    names = sorted(n for f in FOLDERS for n in B.material_names(f))[:: args.every]
    jobs = [(n, m, args.no_prior) for m in args.slices.split(",") for n in names]
    t0 = time.perf_counter()
    with ProcessPoolExecutor(args.workers) as ex:
        rows = list(ex.map(one, jobs))
    print(f"{len(names)} materials (every {args.every}th), {time.perf_counter() - t0:.0f} s")
    if args.json:
        import json

        Path(args.json).write_text(json.dumps(rows, indent=1))
    for mode in args.slices.split(","):
        rs = [r for r in rows if r["mode"] == mode]
        ks = KS_NO_PRIOR if args.no_prior else KS
        print(f"\ncase {mode} ({B._label(mode)}), auto "
              + ("without a prior (bound: the analytic family)" if args.no_prior else "with the prior, leave-one-out")
              + ":")
        print("variant            linear median / worst   > 50 %   PSNR median / worst   cosl2 median")
        for key in ("unbounded", *(f"bound k={k:g}" for k in ks)):
            lin = np.array([r[key][0] for r in rs])
            ps = np.array([r[key][1] for r in rs])
            c = np.array([r[key][2] for r in rs])
            e = [r[f"energy {key[6:]}"] for r in rs] if key.startswith("bound") else [0.0]
            print(f"{key:18s} {np.median(lin):7.1%} / {lin.max():7.1%}   {int((lin > 0.5).sum()):5d}   "
                  f"{np.median(ps):6.2f} / {ps.min():5.2f} dB     {np.median(c):6.1%}"
                  f"   energy removed median {np.median(e):.1%}, most {max(e):.1%}")
        worst = max(rs, key=lambda r: r["bound k=1"][0])
        print(f"worst with the bound: {worst['material']} ({worst['used']}) {worst['bound k=1'][0]:.1%}")
        rho = spearmanr([r["expected_linear"] for r in rs], [r["bound k=1"][0] for r in rs]).statistic
        print(f"rank correlation of the expected and the actual linear image error (bounded table): {rho:.2f} "
              f"(target >= 0.7)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
