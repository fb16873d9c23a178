"""auto's choice against every candidate it scored, per real material and capture (issue 50).

For each material of ``../shared/realdata`` (never copied into the project) and each capture of
bench_monotone.py (the same samples), ``auto`` is run (``--modes prior``: the other materials as the prior,
leave-one-out; ``none``: without), and then every candidate it cross-validated (fit, microfacet, revolve,
bivariate, prior and its anchored blends) is built on all samples, its table bounded as ``gonio-reconstruct``
writes auto's table, and judged as bench_monotone.py judges (a sphere rendered with it and with the material's own
MERL table, PSNR of the tone-mapped images). One JSON record per material, capture and mode holds each candidate's
held-out image error and relative RMSE (auto's cross-validation) beside its PSNR, and auto's choice.

Printed: per capture, auto's median PSNR, the best candidate's (an oracle that knows the truth), and how often auto
chose within 0.5 / 2 dB of the best; per pair of captures of bench_monotone.py, how many materials lose more than
0.5 / 2 dB with auto's choice and with each fixed candidate. ``--from-jsonl`` re-summarises a run's records.

Usage::

    .venv/bin/python benchmarks/bench_choice.py [--every 3] [--modes prior] [--captures 40,40/70,20/40/60]
        [--workers 2] [--jsonl out/choice.jsonl] [--from-jsonl FILE]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
import warnings
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_monotone as BM  # noqa: E402
import bench_real_materials as BR  # noqa: E402


def _judge(rec: Any, s: Any, opts: Any, ref_images: Any, size: int) -> tuple[float, float]:
    """PSNR (dB) of ``rec``'s table against the truth's renders: (bounded as auto's table is written, as the
    method wrote it)."""
    from reconstruction import pipeline
    from reconstruction.core import merltable
    from reconstruction.report import compare as cmp

    own = pipeline.tabulate(rec)
    _, table, _, _ = pipeline.bound_where_unmeasured(rec, own, s, opts)
    out = []
    for t in (table, own):
        a = cmp.Brdf("candidate", "merl", merltable.brdf_of(BR._as_read(t)), BR._as_read(t))
        out.append(float(cmp.image_metrics(cmp.render_images(a, size), ref_images, size)["psnr_db"]))
    return out[0], out[1]


def run_material(job: dict[str, Any]) -> list[dict[str, Any]]:
    """Worker: one material, every capture and mode; one record each (module doc)."""
    warnings.simplefilter("ignore")
    from threadpoolctl import threadpool_limits

    from reconstruction import pipeline
    from reconstruction.core import merltable
    from reconstruction.methods import Options
    from reconstruction.methods.prior import AnchoredPrior
    from reconstruction.report import compare as cmp

    name, size = job["name"], job["size"]
    out = []
    with threadpool_limits(1), np.errstate(all="ignore"):
        mat, truth = BR.material_truth(name, job["folder"], job["cache"])
        ref_images = cmp.render_images(cmp.Brdf(name, "merl", merltable.brdf_of(truth), truth), size)
        for spec in job["captures"]:
            s = BM.capture_slice(mat, spec).sorted()
            for mode in job["modes"]:
                opts = Options(prior=job["prior"] if mode == "prior" else None,
                               prior_exclude=(name,) if mode == "prior" else ())
                rec: dict[str, Any] = {"material": name, "database": BR.database_of(job["folder"], name),
                                       "capture": spec, "mode": mode}
                t0 = time.perf_counter()
                try:
                    chosen, choice = pipeline.reconstruct(s, "auto", opts)
                    cv = choice["cross_validation"]
                    rec["used"] = cv["chosen_label"]
                    rec["seconds"] = round(time.perf_counter() - t0, 2)
                    built: dict[str, Any] = {}
                    cands = {}
                    for sc in cv["scores"]:  # a handful
                        label, method = sc["label"], sc["method"]
                        entry = {"image_error": sc["held_out_image_error"],
                                 "error": sc["held_out_relative_rmse_cos"], "fold_errors": sc["fold_errors"]}
                        try:
                            if sc.get("variant"):
                                raise ValueError("fit's BIC variant (a scene's) is not judged here")
                            if method not in built:
                                built[method] = pipeline.reconstruct(s, method, opts.replace(prior_anchor=0.0))[0]
                            r = built[method]
                            if sc.get("prior_anchor"):
                                if "bivariate" not in built:
                                    built["bivariate"] = pipeline.reconstruct(s, "bivariate", opts)[0]
                                r = AnchoredPrior(built["prior"], built["bivariate"], float(sc["prior_anchor"]))
                            entry["psnr_db"], entry["psnr_unbounded_db"] = _judge(r, s, opts, ref_images, size)
                        except Exception as e:  # noqa: BLE001 - a benchmark reports a failure and goes on
                            entry["failure"] = f"{type(e).__name__}: {e}"
                        cands[label] = entry
                    rec["candidates"] = cands
                    rec["psnr_db"], rec["psnr_unbounded_db"] = _judge(chosen, s, opts, ref_images, size)
                except Exception as e:  # noqa: BLE001 - a benchmark reports a failure and goes on
                    rec["error"] = f"{type(e).__name__}: {e}"
                rec["total_seconds"] = round(time.perf_counter() - t0, 2)
                out.append(rec)
    return out


def _psnr(r: dict[str, Any], label: str | None = None) -> float:
    """A record's PSNR (dB): auto's (``label`` None), a candidate's, or the best candidate's (``label`` "best")."""
    if label is None:
        return float(r["psnr_db"])
    if label == "best":
        return max((v.get("psnr_db", -np.inf) for v in r["candidates"].values()), default=np.nan)
    return float(r["candidates"].get(label, {}).get("psnr_db", np.nan))


def _worse(pair: list[tuple[dict[str, Any], dict[str, Any]]], la: str | None, lb: str | None) -> str:
    """"3/1": of the (A, B) records, how many lose more than 0.5 / 2 dB from A's ``la`` to B's ``lb``."""
    d = np.array([_psnr(rb, lb) - _psnr(ra, la) for ra, rb in pair])
    return f"{int(np.sum(d < -0.5))}/{int(np.sum(d < -2))}"


def summarise(records: list[dict[str, Any]], modes: list[str]) -> list[str]:
    """The summary's lines (module doc): per capture auto against the best candidate; per pair the materials worse
    by more than 0.5 / 2 dB with auto, with each candidate alone, with the best candidate on both (an oracle that
    knows the truth) and with the best candidate on B after auto's choice on A."""
    lines = []
    for mode in modes:
        rs = [r for r in records if r["mode"] == mode and "candidates" in r]
        by = {(r["material"], r["capture"]): r for r in rs}
        mats = sorted({r["material"] for r in rs})
        caps = [c for c in BM.CAPTURES if any(r["capture"] == c for r in rs)]
        labels = sorted({k for r in rs for k in r["candidates"]})
        lines.append(f"{'with the prior (leave-one-out)' if mode == 'prior' else 'without a prior'} "
                     f"[{len(mats)} materials]:")
        for c in caps:
            here = [by[m, c] for m in mats if (m, c) in by]
            auto = np.array([_psnr(r) for r in here])
            gap = np.array([_psnr(r, "best") for r in here]) - auto
            per = ", ".join(f"{k} {np.nanmedian([_psnr(r, k) for r in here]):.1f}" for k in labels)
            lines.append(f"  {c:10s} PSNR median: auto {np.median(auto):.1f} dB, the best candidate "
                         f"{np.median(auto + gap):.1f}; auto within 0.5 / 2 dB of the best on {np.mean(gap <= 0.5):.0%}"
                         f" / {np.mean(gap <= 2):.0%}; each candidate: {per}")
        lines.append("  pair (A -> B): materials worse by > 0.5 dB / > 2 dB with auto; each candidate alone; the best "
                     "candidate on A and on B (oracle); auto on A, the best candidate on B")
        for a, b in BM.PAIRS:
            ms = [m for m in mats if (m, a) in by and (m, b) in by]
            if not ms:
                continue
            pair = [(by[m, a], by[m, b]) for m in ms]
            lines.append(f"  {a:>10s} -> {b:12s} of {len(ms)}: auto {_worse(pair, None, None)}; "
                         + ", ".join(f"{k} {_worse(pair, k, k)}" for k in labels)
                         + f"; oracle {_worse(pair, 'best', 'best')}; auto then best {_worse(pair, None, 'best')}")
    return lines


def replay(records: list[dict[str, Any]], mode: str, method: str, margin: float) -> list[str]:
    """Another choice rule on the recorded scores (``--prefer METHOD:MARGIN``): from several slices, ``method``
    unless another candidate's held-out image error is ``margin`` times lower; from one slice, the lowest. Lines:
    the PSNR medians per capture and the pairs' materials worse by > 0.5 / 2 dB, beside the same replay without the
    preference (the plain lowest error; it may differ from auto's recorded choice where auto refused a table)."""
    rs = [r for r in records if r["mode"] == mode and "candidates" in r]
    by = {(r["material"], r["capture"]): r for r in rs}
    mats = sorted({r["material"] for r in rs})
    caps = [c for c in BM.CAPTURES if any(r["capture"] == c for r in rs)]
    lines = []
    for name, m, k in (("lowest held-out error", method, 1.0), (f"{method} unless {margin:g}x", method, margin)):
        def chosen(r: dict[str, Any], m: str = m, k: float = k) -> float:
            single = "/" not in r["capture"].split("+")[0] and "+" not in r["capture"]
            ok = {lab: v for lab, v in r["candidates"].items() if "psnr_db" in v and v["image_error"] is not None}
            lab = min(ok, key=lambda cand: ok[cand]["image_error"] * (1.0 if single or cand == m else k))
            return float(ok[lab]["psnr_db"])

        ps = {key: chosen(r) for key, r in by.items()}
        meds = " / ".join(f"{np.median([ps[x, c] for x in mats if (x, c) in ps]):.1f}" for c in caps)
        pairs = []
        for a, b in BM.PAIRS:
            d = np.array([ps[x, b] - ps[x, a] for x in mats if (x, a) in ps and (x, b) in ps])
            if d.size:
                pairs.append(f"{a} -> {b} {int(np.sum(d < -0.5))}/{int(np.sum(d < -2))}")
        lines.append(f"  replay, {name}: medians {meds} dB ({', '.join(caps)}); worse by > 0.5 / 2 dB: "
                     + ", ".join(pairs))
    return lines


def _line(r: dict[str, Any]) -> str:
    """A record as it arrives: auto's PSNR and choice, the best candidate's."""
    best = max(((v.get("psnr_db", -np.inf), k) for k, v in r.get("candidates", {}).items()), default=(np.nan, "-"))
    return (f"{r['material']:34s} {r['mode']:5s} {r['capture']:12s} "
            + (f"auto {r['psnr_db']:5.1f} dB [{r['used']}], best {best[0]:5.1f} [{best[1]}] {r['total_seconds']:.0f} s"
               if "psnr_db" in r else f"FAILED: {r['error']}"))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    BM.material_arguments(ap, every=3, captures="40,40/70,20/40/60", modes="prior", size=128,
                          jsonl=ROOT / "out" / "choice.jsonl")
    ap.add_argument("--prefer", metavar="METHOD:MARGIN", help="with --from-jsonl: replay a preference for METHOD "
                    "from several slices on the recorded scores (e.g. bivariate:1.5)")
    args = ap.parse_args(argv)
    modes = [m for m in args.modes.split(",") if m]
    if args.from_jsonl:
        recs = [json.loads(x) for x in Path(args.from_jsonl).read_text().splitlines() if x.strip()]
        print("\n".join(summarise(recs, [m for m in modes if any(r["mode"] == m for r in recs)])))
        if args.prefer:
            method, _, margin = args.prefer.partition(":")
            for m in modes:
                print("\n".join(replay(recs, m, method, float(margin or 1.0))))
        return 0
    jobs = BM.material_jobs(args, modes, [c for c in args.captures.split(",") if c], "bench_choice")
    if jobs is None:
        return 2
    t0 = time.perf_counter()
    records = BM.run_jobs(run_material, jobs, args.workers, args.jsonl, _line)
    print("\n".join(summarise(records, modes)))
    print(f"{len(jobs)} materials, {len(records)} records, {time.perf_counter() - t0:.0f} s wall with "
          f"{args.workers} worker(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
