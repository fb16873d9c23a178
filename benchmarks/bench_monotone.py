"""Does every sweep add? For captures A within B (B = A plus sweeps), the PSNR of the table written from B minus
that from A, per real material (issue 50).

Each material of ``../shared/realdata`` (never copied into the project) is measured as a bench measures it
(bench_real_materials.py: theta_o = -80..80 deg by 2 deg, the blind spot |theta_i + theta_o| < 4 deg left out) in
every capture of :data:`CAPTURES`: in-plane slices (``40/70``: incidences 40 and 70 deg) and sweeps with the sample
tilted (``40t30``: the light arm at 40 deg, the detector arm swept as above, the sample tilted by 30 deg about the
axis in the arms' plane; in the sample's frame the light is (-sin a, cos a sin t, cos a cos t) and the detector
(sin b, cos b sin t, cos b cos t), :func:`reconstruction.core.geometry.tilted_to_dirs`). A capture with tilted
sweeps is handed to the methods as a :class:`~reconstruction.core.samples.SliceWithPoints` (its in-plane rows, and
every sample as points), as a file with a ``tilt_deg`` column is read. ``auto`` (``--prior``: with the other
materials as the prior, leave-one-out; ``--no-prior``: without) reconstructs each, the table is bounded as
``gonio-reconstruct`` writes it, and a sphere is rendered with it and with the material's own MERL table (key and rim
lighting, PSNR of the tone-mapped images; bench_real_materials.py's image metric).

Printed: per capture the PSNR median / worst; per pair of :data:`PAIRS` the median and worst of PSNR(B) - PSNR(A)
over materials and how many are worse by more than 0.5 and 2 dB; the tilt question at equal bench time
(:data:`TILT_QUESTION`: from the same sweeps already taken, one more in-plane incidence against one tilted sweep,
each sweep's bench time from the advice's time model, :class:`reconstruction.assess.advice.BenchLimits`).

Usage::

    .venv/bin/python benchmarks/bench_monotone.py [--every 6] [--offset 0] [--modes prior,none] [--workers 1]
        [--jsonl out/monotone.jsonl] [--from-jsonl FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from collections.abc import Callable
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import bench_real_materials as BR  # noqa: E402

from reconstruction.core.geometry import tilted_to_dirs  # noqa: E402
from reconstruction.core.samples import SliceWithPoints, directional_slice  # noqa: E402
from reconstruction.core.slicedata import Slice  # noqa: E402

#: the captures, each reconstructed once per material and mode
CAPTURES = ("40", "40/70", "20/40/60", "20/40/70", "20/40/60/70", "40+40t30", "40/70+40t35", "40/70+40t35+70t35",
            "20/40/60+40t30")
#: (A, B): B holds every sweep of A and more
PAIRS = (("40", "40/70"), ("40", "20/40/60"), ("40/70", "20/40/70"), ("20/40/60", "20/40/60/70"),
         ("40", "40+40t30"), ("40/70", "40/70+40t35"), ("40/70+40t35", "40/70+40t35+70t35"),
         ("40/70", "40/70+40t35+70t35"), ("20/40/60", "20/40/60+40t30"))
#: (sweeps taken, one more in-plane incidence, one tilted sweep instead)
TILT_QUESTION = (("40", "40/70", "40+40t30"), ("40/70", "20/40/70", "40/70+40t35"),
                 ("20/40/60", "20/40/60/70", "20/40/60+40t30"))
#: a tilt move before a tilted sweep (s): a servo turning the sample by 30-35 deg at the light arm's speed
TILT_MOVE_S = 1.0


def parse_capture(spec: str) -> tuple[tuple[float, ...], tuple[tuple[float, float], ...]]:
    """(in-plane incidences, tilted sweeps (arm angle, tilt)) of a capture ``40/70+40t35`` (deg)."""
    parts = spec.split("+")
    inplane = tuple(float(x) for x in parts[0].split("/") if x) if "t" not in parts[0] else ()
    tilted = tuple((float(a), float(t)) for p in parts[(1 if inplane else 0):] for a, t in [p.split("t")])
    return inplane, tilted


def sweep_angles(arm_i: float) -> np.ndarray:
    """The detector arm's angles (deg) of one sweep at light arm ``arm_i``: -80..80 by 2, the blind spot left out."""
    to = np.arange(-BR.MAX_DEG, BR.MAX_DEG + 1e-9, BR.STEP_DEG)
    return to[np.abs(to + arm_i) >= BR.BLIND_DEG]


def capture_slice(mat: Any, spec: str) -> Slice:
    """The samples of capture ``spec`` of material ``mat`` (module doc)."""
    inplane, tilted = parse_capture(spec)
    s = BR.slices_of(mat, inplane)
    if not tilted:
        return s
    a = np.concatenate([np.full(sweep_angles(ai).size, ai) for ai, _ in tilted])
    b = np.concatenate([sweep_angles(ai) for ai, _ in tilted])
    t = np.concatenate([np.full(sweep_angles(ai).size, ti) for ai, ti in tilted])
    wi, wo = tilted_to_dirs(np.radians(a), np.radians(b), np.radians(t))
    wi_p, wo_p = BR.inplane_to_dirs(np.radians(s.theta_i_deg), np.radians(s.theta_o_deg))
    wi, wo = np.concatenate([wi_p, wi]), np.concatenate([wo_p, wo])
    f = mat.eval(wi, wo)
    pts = directional_slice(wi, wo, f, ["R", "G", "B"], source=f"{mat.name} ({spec})")
    return SliceWithPoints(s.theta_i_deg, s.theta_o_deg, s.values, s.channels, s.std, source=s.source, points=pts)


def bench_time_s(spec: str) -> float:
    """The capture's bench time (s): points x the advice's time per point, and a tilt move per tilted sweep."""
    from reconstruction.assess.advice import BenchLimits

    inplane, tilted = parse_capture(spec)
    n = sum(sweep_angles(t).size for t in inplane) + sum(sweep_angles(a).size for a, _ in tilted)
    return n * BenchLimits().point_s + TILT_MOVE_S * len(tilted)


def run_material(job: dict[str, Any]) -> list[dict[str, Any]]:
    """Worker: one material, every capture and mode; one record each."""
    warnings.simplefilter("ignore")
    from threadpoolctl import threadpool_limits

    from reconstruction.core import merltable
    from reconstruction.report import compare as cmp

    name, folder, size = job["name"], job["folder"], job["size"]
    out = []
    with threadpool_limits(1), np.errstate(all="ignore"):
        mat, truth = BR.material_truth(name, folder, job["cache"])
        ref_images = cmp.render_images(cmp.Brdf(name, "merl", merltable.brdf_of(truth), truth), size)
        for spec in job["captures"]:
            s = capture_slice(mat, spec)
            for mode in job["modes"]:
                rec: dict[str, Any] = {"material": name, "database": BR.database_of(folder, name), "capture": spec,
                                       "mode": mode}
                t0 = time.perf_counter()
                try:
                    method = "auto+prior" if mode == "prior" else "auto"
                    table, facts = BR._reconstruct(method, s, job["prior"], name)
                    rec.update(seconds=round(time.perf_counter() - t0, 2), used=facts.get("chosen_label"))
                    a = cmp.Brdf(spec, "merl", merltable.brdf_of(BR._as_read(table)), BR._as_read(table))
                    rec["psnr_db"] = cmp.image_metrics(cmp.render_images(a, size), ref_images, size)["psnr_db"]
                except Exception as e:  # a benchmark reports a failure and goes on
                    rec.update(error=f"{type(e).__name__}: {e}", seconds=time.perf_counter() - t0)
                out.append(rec)
    return out


def summarise(records: list[dict[str, Any]], modes: list[str]) -> list[str]:
    """The summary's lines: per capture, per pair, the tilt question."""
    lines = []
    for mode in modes:
        by = {(r["material"], r["capture"]): r.get("psnr_db", np.nan) for r in records if r["mode"] == mode}
        used = {(r["material"], r["capture"]): r.get("used") for r in records if r["mode"] == mode}
        mats = sorted({m for m, _ in by})
        lines.append(f"{'with the prior (leave-one-out)' if mode == 'prior' else 'without a prior'} "
                     f"[{len(mats)} materials]:")
        for c in CAPTURES:
            v = np.array([by.get((m, c), np.nan) for m in mats])
            if np.isfinite(v).any():
                lines.append(f"  {c:20s} PSNR median {np.nanmedian(v):5.1f} / worst {np.nanmin(v):5.1f} dB  "
                             f"({bench_time_s(c):5.0f} s of bench time)")
        lines.append("  pair (A -> B): PSNR(B) - PSNR(A) median / worst (material); worse by > 0.5 dB, > 2 dB")
        for a, b in PAIRS:
            d = np.array([by.get((m, b), np.nan) - by.get((m, a), np.nan) for m in mats])
            ok = np.isfinite(d)
            if not ok.any():
                continue
            k = int(np.nanargmin(d))
            lines.append(f"  {a:>12s} -> {b:20s} {np.nanmedian(d):+5.2f} / {d[k]:+6.2f} dB ({mats[k]}); "
                         f"{int(np.sum(d[ok] < -0.5))} ({np.mean(d[ok] < -0.5):.0%}), {int(np.sum(d[ok] < -2.0))} "
                         f"of {int(ok.sum())}")
            worse = [(d[j], mats[j]) for j in np.nonzero(ok & (d < -2.0))[0]]
            switched = sum(used.get((m, a)) != used.get((m, b)) for _, m in worse)
            if worse:  # which method lost it: auto switching (A's method -> B's) or the same method
                lines.append(f"      worse by > 2 dB ({switched} of {len(worse)} with another method on B): "
                             + ", ".join(f"{m} {x:+.1f} [{used.get((m, a))} -> {used.get((m, b))}]"
                                         for x, m in sorted(worse)))
        lines.append("  at equal bench time, from the sweeps taken: + one in-plane incidence / + one tilted sweep "
                     "(median PSNR; median of tilted - in-plane; tilted better by > 0.5 dB / worse by > 0.5 dB)")
        for base, inpl, tilt in TILT_QUESTION:
            x = np.array([by.get((m, inpl), np.nan) for m in mats])
            y = np.array([by.get((m, tilt), np.nan) for m in mats])
            d = y - x
            if not np.isfinite(d).any():
                continue
            lines.append(f"  {base:>10s}: {inpl} {np.nanmedian(x):5.1f} dB ({bench_time_s(inpl):.0f} s) / {tilt} "
                         f"{np.nanmedian(y):5.1f} dB ({bench_time_s(tilt):.0f} s); {np.nanmedian(d):+.2f} dB; "
                         f"{int(np.sum(d > 0.5))} / {int(np.sum(d < -0.5))}")
    return lines


def material_arguments(ap: argparse.ArgumentParser, every: int, captures: str, modes: str, size: int,
                       jsonl: Path) -> None:
    """The options of a benchmark over the real materials (this one's and bench_choice.py's), with its defaults."""
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "realdata"))
    ap.add_argument("--every", type=int, default=every, help="every N-th material of the 141 by name (1: all)")
    ap.add_argument("--offset", type=int, default=0)
    ap.add_argument("--materials", help="comma-separated names instead")
    ap.add_argument("--captures", default=captures, help="comma-separated captures (bench_monotone.py's doc)")
    ap.add_argument("--modes", default=modes, help="prior (auto with the prior), none (auto without)")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--size", type=int, default=size, help="the renders' size (pixels)")
    ap.add_argument("--cache", default=str(ROOT / "out" / "real-materials-cache"))
    ap.add_argument("--jsonl", default=str(jsonl))
    ap.add_argument("--from-jsonl", metavar="FILE", help="summarise the records of FILE; run nothing")


def material_jobs(args: argparse.Namespace, modes: list[str], captures: list[str], prog: str
                  ) -> list[dict[str, Any]] | None:
    """One job per material of ``args`` (``--data``, ``--every``, ``--offset``, ``--materials``, ``--cache``,
    ``--size``): its name, folder, the captures and modes, the prior (every folder; tabulated and cached here, before
    the workers start, when a mode uses it). None, said on stderr, when the real data is not there."""
    data = Path(args.data)
    folders = [data / f for f in BR.FOLDERS if (data / f).is_dir()]
    if not folders:
        print(f"{prog}: {data}/nbrdf-merl not found (see ../shared/realdata/README.md)", file=sys.stderr)
        return None
    where = {n: str(f) for f in folders for n in BR.material_names(f)}
    names = sorted(where)[args.offset:: args.every] if not args.materials else args.materials.split(",")
    prior = os.pathsep.join(str(f) for f in folders)
    if "prior" in modes:
        from reconstruction.methods.prior import load_prior

        load_prior(prior)
    return [{"name": n, "folder": where[n], "captures": captures, "modes": modes, "prior": prior,
             "cache": args.cache, "size": args.size} for n in names]


def run_jobs(worker: Callable[[dict[str, Any]], list[dict[str, Any]]], jobs: list[dict[str, Any]], workers: int,
             jsonl: str, line: Callable[[dict[str, Any]], str]) -> list[dict[str, Any]]:
    """Every job's records by ``worker`` in ``workers`` processes, each written to ``jsonl`` (one JSON record a line)
    and printed as ``line`` says as it arrives."""
    records: list[dict[str, Any]] = []
    Path(jsonl).parent.mkdir(parents=True, exist_ok=True)
    with open(jsonl, "w", encoding="utf-8") as log, ProcessPoolExecutor(max(1, workers)) as ex:
        for fut in as_completed([ex.submit(worker, j) for j in jobs]):
            for r in fut.result():
                records.append(r)
                log.write(json.dumps(r) + "\n")
                print(line(r), flush=True)
            log.flush()
    return records


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    material_arguments(ap, every=6, captures=",".join(CAPTURES), modes="prior,none", size=64,
                       jsonl=ROOT / "out" / "monotone.jsonl")
    args = ap.parse_args(argv)
    modes = [m for m in args.modes.split(",") if m]
    if args.from_jsonl:
        recs = [json.loads(x) for x in Path(args.from_jsonl).read_text().splitlines() if x.strip()]
        print("\n".join(summarise(recs, [m for m in modes if any(r["mode"] == m for r in recs)])))
        return 0
    jobs = material_jobs(args, modes, [c for c in args.captures.split(",") if c], "bench_monotone")
    if jobs is None:
        return 2
    t0 = time.perf_counter()
    records = run_jobs(run_material, jobs, args.workers, args.jsonl, lambda r: (
        f"{r['material']:34s} {r['mode']:5s} {r['capture']:20s} "
        + (f"PSNR {r['psnr_db']:5.1f} dB [{r.get('used')}] {r['seconds']:.1f} s" if "psnr_db" in r
           else f"FAILED: {r['error']}")))
    print("\n".join(summarise(records, modes)))
    print(f"{len(jobs)} materials, {len(records)} reconstructions, {time.perf_counter() - t0:.0f} s wall with "
          f"{args.workers} worker(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
