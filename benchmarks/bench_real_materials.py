"""Reconstruction on real measured materials: every method and ``auto``, from 1 and from 3 in-plane slices.

Reads the 48 MERL materials of ``../shared/realdata/nbrdf-merl`` (neural BRDFs, see its README; never copied into
the project), extracts in-plane slices as a bench would measure them (theta_o = -80..80 deg by 2 deg, the blind
spot |theta_i + theta_o| < 4 deg left out; 1 slice at theta_i = 40 deg, 3 slices at 20/40/60 deg), reconstructs
with every method and ``auto``, and compares each table with the material's own table:

* ``rmse80``: relative RMSE of f cos(theta_i) cos(theta_o) over every cell with both angles <= 80 deg;
* ``medrel``: the median relative error of f over those cells where f is above 1 % of its maximum;
* ``plausible``: the table passes the plausibility checks (non-negative, directional albedo <= 1 + 0.01 at every
  incidence, reciprocity) that gonio-reconstruct applies before it writes a table;
* the reconstruction time (method + tabulation).

Prints a line per material and method, then the median and the worst material per method; with ``--docs DIR``
writes ``DIR/real-materials.md`` (the whole table) and ``DIR/real-materials.png`` (error per material and
method). Usage::

    .venv/bin/python benchmarks/bench_real_materials.py [--data ../shared/realdata] [--materials chrome,steel]
        [--methods auto,fit,microfacet,revolve,bivariate] [--workers 2] [--docs docs]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction import pipeline  # noqa: E402
from reconstruction.core.geometry import inplane_to_dirs  # noqa: E402
from reconstruction.core.metrics import (  # noqa: E402
    _table_cosines,
    median_relative_error,
    relative_rmse_cos,
    relative_rmse_cos_by_theta_d,
    within_angle_mask,
)
from reconstruction.core.models import NBRDF_SUFFIXES, Material  # noqa: E402
from reconstruction.formats import merl  # noqa: E402
from reconstruction.formats.slicefile import Slice  # noqa: E402
from reconstruction.report import summary as report  # noqa: E402

MODES = {"1": (40.0,), "3": (20.0, 40.0, 60.0)}
STEP_DEG, BLIND_DEG, MAX_DEG = 2.0, 4.0, 80.0
THETA_D_EDGES = (0.0, 30.0, 45.0, 60.0, 90.0)  # bands of theta_d (deg) for the split of rmse80
GRAZING_DEG = 60.0  # theta_d above what a 40 deg slice sees at its specular peak and beyond the 3 slices' peaks


def grazing_level(table: np.ndarray, truth: np.ndarray) -> float:
    """||f c|| / ||g c|| over the cells within 80 deg with theta_d >= GRAZING_DEG: the reconstruction's level
    where no slice of the cases 1 and 3 reaches the specular peak (1 = right level, 2 = twice too bright)."""
    c = _table_cosines()[None]
    td = (np.arange(90) + 0.5)[None, None, :, None]
    m = within_angle_mask(MAX_DEG)[None] & (td >= GRAZING_DEG) & np.isfinite(table) & np.isfinite(truth)
    den = np.sqrt(np.sum(np.where(m, truth * c, 0.0) ** 2))
    return float(np.sqrt(np.sum(np.where(m, table * c, 0.0) ** 2)) / den) if den > 0 else float("nan")


def material_names(folder: Path) -> list[str]:
    """Every NAME with the six NAME_{fc1,b1,fc2,b2,fc3,b3}.npy files in ``folder``, sorted."""
    names = {p.name[: -len(f"_{NBRDF_SUFFIXES[0]}.npy")] for p in folder.glob(f"*_{NBRDF_SUFFIXES[0]}.npy")}
    return sorted(n for n in names if all((folder / f"{n}_{s}.npy").is_file() for s in NBRDF_SUFFIXES))


def slices_of(mat: Material, incidences: tuple[float, ...]) -> Slice:
    """In-plane samples of ``mat`` as the benchmark defines them (README of the real data)."""
    to = np.arange(-MAX_DEG, MAX_DEG + 1e-9, STEP_DEG)
    ti_all, to_all = [], []
    for t in incidences:
        o = to[np.abs(to + t) >= BLIND_DEG]
        ti_all.append(np.full(o.size, t))
        to_all.append(o)
    a, b = np.concatenate(ti_all), np.concatenate(to_all)
    f = mat.eval(*inplane_to_dirs(np.radians(a), np.radians(b)))
    return Slice(a, b, f, ["R", "G", "B"], np.zeros_like(f), source=f"{mat.name} ({len(incidences)} slice(s))")


def run_material(job: tuple[str, str, list[str], str | None, list[str], str | None]) -> list[dict[str, Any]]:
    """Worker: the truth table of one material, then every method and mode; one record per (mode, method)."""
    name, folder, methods, cache, modes, prior = job
    warnings.simplefilter("ignore")
    from threadpoolctl import threadpool_limits

    with threadpool_limits(1):
        mat = Material.from_dict({"name": name, "lobes": [{"type": "nbrdf", "path": str(Path(folder) / name)}]})
        cached = Path(cache) / f"{name}.npy" if cache else None
        if cached is not None and cached.is_file():
            truth = np.load(cached).astype(np.float64)
        else:
            truth = merl.tabulate(mat.eval)
            if cached is not None:
                cached.parent.mkdir(parents=True, exist_ok=True)
                np.save(cached, truth.astype(np.float32))
        out = []
        for mode in modes:
            s = slices_of(mat, incidences_of(mode))
            for m in methods:
                t0 = time.perf_counter()
                rec_out: dict[str, Any] = {"material": name, "slices": mode, "method": m}
                try:
                    # the prior, when given, is the other materials of the folder (leave-one-out)
                    opts = pipeline.Options(prior=prior, prior_exclude=(name,) if prior else ())
                    rec, choice = pipeline.reconstruct(s, m, opts)
                    table = pipeline.tabulate(rec)
                    rec_out["seconds"] = time.perf_counter() - t0
                    checks = report.plausibility(rec, table)
                    rec_out.update(used=choice["used"], rmse80=relative_rmse_cos(table, truth, MAX_DEG),
                                   medrel=median_relative_error(table, truth, MAX_DEG),
                                   rmse80_theta_d=relative_rmse_cos_by_theta_d(table, truth, MAX_DEG,
                                                                               THETA_D_EDGES).tolist(),
                                   grazing_level=grazing_level(table, truth),
                                   plausible=bool(checks["all_pass"]), max_albedo=float(checks["albedo"]["max"]))
                    if "cross_validation" in choice:
                        scores = choice["cross_validation"]["scores"]
                        rec_out["cv_seconds"] = sum(c["seconds"] for c in scores)
                        rec_out["cv"] = {c.get("label", c["method"]): c["held_out_relative_rmse_cos"] for c in scores}
                        rec_out["cv_folds"] = {c.get("label", c["method"]): c["fold_errors"] for c in scores}
                        rec_out["chosen_label"] = choice["cross_validation"].get("chosen_label", choice["used"])
                except Exception as e:  # a benchmark reports a failure and goes on
                    rec_out.update(error=f"{type(e).__name__}: {e}", seconds=time.perf_counter() - t0)
                out.append(rec_out)
    return out


def incidences_of(mode: str) -> tuple[float, ...]:
    """The incidences (deg) of a case: ``1`` (40), ``3`` (20/40/60) or any ``A/B/...`` list such as ``20/50/75``."""
    if mode in MODES:
        return MODES[mode]
    try:
        inc = tuple(float(x) for x in mode.split("/"))
    except ValueError:
        raise ValueError(f"case {mode!r}: expected 1, 3 or incidences in deg such as 20/50/75") from None
    if not inc or any(not 0.0 <= t <= MAX_DEG for t in inc):
        raise ValueError(f"case {mode!r}: incidences must lie in 0..{MAX_DEG:g} deg")
    return inc


def _label(mode: str) -> str:
    inc = incidences_of(mode)
    return f"{len(inc)} slice(s) at {'/'.join(f'{t:g}' for t in inc)} deg"


def summarise(records: list[dict[str, Any]], methods: list[str]) -> list[str]:
    """Lines: per mode and method, median and worst rmse80 / medrel, plausibility, times; auto vs the best."""
    lines = []
    for mode in dict.fromkeys(r["slices"] for r in records):
        lines.append(f"{_label(mode)}:")
        for m in methods:
            rs = [r for r in records if r["slices"] == mode and r["method"] == m]
            ok = [r for r in rs if "rmse80" in r]
            if not ok:
                lines.append(f"  {m:11s} no result")
                continue
            e = np.array([r["rmse80"] for r in ok]) * 100
            md = np.array([r["medrel"] for r in ok]) * 100
            worst = ok[int(np.argmax(e))]
            lines.append(f"  {m:11s} rmse80 median {np.median(e):6.1f} %, worst {e.max():7.1f} % ({worst['material']});"
                         f" medrel median {np.median(md):5.1f} %, worst {md.max():6.1f} %;"
                         f" > 50 %: {int(np.sum(e > 50))}"
                         f"; implausible tables: {sum(not r['plausible'] for r in ok)}; failed: {len(rs) - len(ok)};"
                         f" time median {np.median([r['seconds'] for r in ok]):.2f} s, max "
                         f"{max(r['seconds'] for r in ok):.2f} s")
            if all("rmse80_theta_d" in r for r in ok):
                parts = np.array([r["rmse80_theta_d"] for r in ok]) ** 2
                share = parts[:, -1] / np.maximum(parts.sum(axis=1), 1e-300) * 100
                lv = np.array([r["grazing_level"] for r in ok])
                q = np.nanpercentile(lv, [10, 50, 90])
                lines.append(f"  {'':11s} share of rmse80^2 at theta_d >= {GRAZING_DEG:g} deg: median "
                             f"{np.median(share):4.0f} % (mean {share.mean():.0f} %); "
                             f"level there (table/truth) 10/50/90 %: "
                             f"{q[0]:.2f} / {q[1]:.2f} / {q[2]:.2f}")
        if "auto" in methods and len(methods) > 1:
            by = {}
            for r in records:
                if r["slices"] == mode and "rmse80" in r:
                    by.setdefault(r["material"], {})[r["method"]] = r["rmse80"]
            within = sum(1 for v in by.values() if "auto" in v and
                         v["auto"] <= 1.1 * min(x for k, x in v.items() if k != "auto"))
            lines.append(f"  auto within 10 % (relative) of the best method's rmse80: {within} of {len(by)}")
            best = np.array([min(x for k, x in v.items() if k != "auto") for v in by.values()
                             if any(k != "auto" for k in v)]) * 100
            if best.size:  # a bound on any choice among these methods: each material's best, chosen with the truth
                lines.append(f"  the best method per material (chosen with the truth, a bound on any choice): rmse80 "
                             f"median {np.median(best):.1f} %, worst {best.max():.1f} %, "
                             f"> 50 %: {int(np.sum(best > 50))}")
    return lines


NOTES_BEGIN = "<!-- notes: written by hand; bench_real_materials.py --docs keeps this block as it is -->"
NOTES_END = "<!-- /notes -->"


def kept_notes(page: Path) -> str:
    """The hand-written block of an existing ``page`` (between NOTES_BEGIN and NOTES_END, markers included), so a
    regeneration keeps the reading of the figures that people wrote; a placeholder block if there is none."""
    try:
        old = page.read_text(encoding="utf-8")
    except (OSError, UnicodeDecodeError):
        old = ""
    i = old.find(NOTES_BEGIN)
    j = old.find(NOTES_END, i + 1) if i >= 0 else -1
    if i >= 0 and j > i:
        return old[i:j + len(NOTES_END)]
    return f"{NOTES_BEGIN}\n(No notes yet: what the figures say, with the command of any figure quoted.)\n{NOTES_END}"


def write_docs(records: list[dict[str, Any]], methods: list[str], docs: Path, summary: list[str]) -> None:
    """docs/real-materials.md (every figure) and docs/real-materials.png, one panel and one group of columns per
    case run; the page's hand-written notes block (:func:`kept_notes`) is kept."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = sorted({r["material"] for r in records})
    modes = list(dict.fromkeys(r["slices"] for r in records))
    fig, axes = plt.subplots(len(modes), 1, figsize=(15, 1.5 + 3.75 * len(modes)), sharex=True, squeeze=False)
    axes = axes[:, 0]
    for ax, mode in zip(axes, modes, strict=True):
        for k, m in enumerate(methods):
            v = {r["material"]: r.get("rmse80", np.nan) * 100 for r in records if r["slices"] == mode and
                 r["method"] == m}
            ax.plot(np.arange(len(names)) + (k - len(methods) / 2) * 0.12, [v.get(n, np.nan) for n in names],
                    "o" if m == "auto" else ".", ms=7 if m == "auto" else 5, label=m,
                    color="k" if m == "auto" else None)
        ax.set_yscale("log")
        ax.axhline(15 if len(incidences_of(mode)) == 1 else 8, color="g", lw=0.8, ls="--", label="median target")
        ax.set_ylabel("rmse80 (%)")
        ax.set_title(_label(mode))
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(ncol=len(methods) + 1, fontsize=8)
    axes[-1].set_xticks(np.arange(len(names)))
    axes[-1].set_xticklabels(names, rotation=75, fontsize=7)
    fig.tight_layout()
    fig.savefig(docs / "real-materials.png", dpi=90)
    rows = ["| material | " + " | ".join(f"{m} ({mode})" for mode in modes for m in methods) + " |",
            "|---|" + "---|" * (len(methods) * len(modes))]
    for n in names:
        cells = []
        for mode in modes:
            for m in methods:
                r = next((r for r in records if r["material"] == n and r["slices"] == mode and r["method"] == m),
                         None)
                if r is None or "rmse80" not in r:
                    cells.append("failed" if r else "")
                else:
                    used = f" [{r.get('chosen_label', r['used'])}]" if m == "auto" else ""
                    flag = "" if r["plausible"] else " (implausible)"
                    cells.append(f"{r['rmse80'] * 100:.1f} / {r['medrel'] * 100:.1f}{used}{flag}")
        rows.append(f"| {n} | " + " | ".join(cells) + " |")
    notes = kept_notes(docs / "real-materials.md")
    text = f"""# Reconstruction on real materials

Regenerate: `.venv/bin/python benchmarks/bench_real_materials.py --slices {",".join(modes)} --docs docs` (reads
`../shared/realdata`, which is not part of the project; about 3-5 minutes per case on 2 cores). It rewrites this
page except the section "Reading the figures", which is written by hand and names the command of every figure it
quotes that this benchmark does not print.

The 48 MERL materials of `../shared/realdata/nbrdf-merl` (neural BRDF fits of the MERL measurements), sliced as
a bench measures them: theta_o from -80 to 80 deg every 2 deg, the blind spot |theta_i + theta_o| < 4 deg left out;
the cases run here: {"; ".join(_label(m) for m in modes)} (the issue's cases are 1 slice at 40 deg and 3 at
20/40/60 deg; a column's heading names its case: 1, 3 or the incidences). Each method's table is compared with the
material's own table. Figures: **rmse80** (relative RMSE of f cos theta_i cos theta_o over every cell with both
angles <= 80 deg) / **medrel** (median relative error of f where f is above 1 % of its maximum, same cells),
in %. `[method]` is the method `auto` chose by cross-validation (`prior (anchor A)`: prior blended with the bivariate
interpolation, f_prior^(1-A) f_bivariate^A); "(implausible)" marks a table that fails the
plausibility checks (gonio-reconstruct refuses to write it without `--allow-implausible`). `prior` (and `auto`,
which tries it) completes each material from a basis of the **other** 47 materials (leave-one-out: a material never
sees itself); the other half of the MERL database is kept apart for independent judging.

## Where the error lies

Under each method's line, the summary splits rmse80 by the difference angle: the share of its square that comes
from cells with theta_d >= 60 deg, and the reconstruction's level there (||f c|| / ||g c|| over those cells, c =
cos theta_i cos theta_o; 1 = right). A slice at incidence theta_i reaches theta_d = theta_i at its specular peak
and (theta_i + 80)/2 at its last sample, so from 40 deg (and from 20/40/60 deg) the grazing specular peak, where
most materials brighten steeply (Fresnel, shadowing), is never measured: every method extrapolates it. Most of
the error is there; the levels' spread (10th to 90th percentile) says how far from the truth that extrapolation
lands. A capture meant for grazing renders needs a slice at high incidence (70-75 deg): see the cases
20/50/75 and 40/70 (`--slices 1,3,20/50/75,40/70`).

## Summary

```
{chr(10).join(summary)}
```

![rmse80 per material and method](real-materials.png)

## Reading the figures

{notes}

## Every material

{chr(10).join(rows)}
"""
    (docs / "real-materials.md").write_text(text, encoding="utf-8")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "realdata"),
                    help="the real-data folder (with nbrdf-merl/); default ../shared/realdata")
    ap.add_argument("--materials", help="comma-separated material names (default: all)")
    ap.add_argument("--methods", default=",".join(pipeline.METHODS),
                    help=f"comma-separated methods (default: {','.join(pipeline.METHODS)})")
    ap.add_argument("--slices", default="1,3",
                    help="which cases, comma-separated: 1 (one slice at 40 deg), 3 (20/40/60 deg), or incidences in "
                         "deg joined by / (e.g. 20/50/75); default 1,3")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="worker processes")
    ap.add_argument("--cache", default=str(ROOT / "out" / "real-materials-cache"),
                    help="folder for the materials' own tables (computed once); '' for none")
    ap.add_argument("--prior", default=None, metavar="DIR",
                    help="prior materials for --method prior and auto (default: the nbrdf-merl folder itself, each "
                         "material judged with a prior of the others: leave-one-out); '' for no prior")
    ap.add_argument("--docs", metavar="DIR", help="write DIR/real-materials.md and DIR/real-materials.png")
    ap.add_argument("--jsonl", default=str(ROOT / "out" / "real-materials.jsonl"), help="every record, one per line")
    args = ap.parse_args(argv)
    folder = Path(args.data) / "nbrdf-merl"
    if not folder.is_dir():
        print(f"bench_real_materials: {folder} not found (see ../shared/realdata/README.md)", file=sys.stderr)
        return 2
    names = material_names(folder)
    if args.materials:
        want = [n.strip() for n in args.materials.split(",") if n.strip()]
        missing = sorted(set(want) - set(names))
        if missing:
            print(f"bench_real_materials: unknown material(s) {missing}", file=sys.stderr)
            return 2
        names = want
    prior = str(folder) if args.prior is None else (args.prior or None)
    methods = [m.strip() for m in args.methods.split(",") if m.strip() and (prior or m.strip() != "prior")]
    bad = [m for m in methods if m not in pipeline.METHODS]
    if bad:
        print(f"bench_real_materials: unknown method(s) {bad}; expected {', '.join(pipeline.METHODS)}", file=sys.stderr)
        return 2
    from tqdm import tqdm

    records: list[dict[str, Any]] = []
    t0 = time.perf_counter()
    modes = [m.strip() for m in args.slices.split(",") if m.strip()]
    try:
        for m in modes:
            incidences_of(m)
    except ValueError as e:
        print(f"bench_real_materials: --slices: {e}", file=sys.stderr)
        return 2
    if prior:
        from reconstruction.methods.prior import load_prior

        load_prior(prior)  # tabulated once (and cached) before the workers start
    jobs = [(n, str(folder), methods, args.cache or None, modes, prior) for n in names]
    with ProcessPoolExecutor(max_workers=max(1, args.workers)) as ex:
        for recs in tqdm(ex.map(run_material, jobs), total=len(jobs), desc="materials", file=sys.stderr):
            records.extend(recs)
            for r in recs:
                if "rmse80" in r:
                    used = f" [{r.get('chosen_label', r['used'])}]" if r["method"] == "auto" else ""
                    print(f"{r['material']:26s} {r['slices']:>8s} {r['method']:11s} "
                          f"rmse80 {r['rmse80'] * 100:7.1f} %"
                          f"  medrel {r['medrel'] * 100:6.1f} %  {'plausible' if r['plausible'] else 'IMPLAUSIBLE'}"
                          f" (albedo max {r['max_albedo']:.3f})  {r['seconds']:5.2f} s{used}")
                else:
                    print(f"{r['material']:26s} {r['slices']:>8s} {r['method']:11s} FAILED: {r['error']}")
    summary = summarise(records, methods)
    summary.append(f"{len(names)} materials, {len(records)} reconstructions, {time.perf_counter() - t0:.0f} s "
                   f"wall with {args.workers} worker(s)")
    print("\n".join(summary))
    if args.jsonl:
        Path(args.jsonl).parent.mkdir(parents=True, exist_ok=True)
        Path(args.jsonl).write_text("".join(json.dumps(r) + "\n" for r in records), encoding="utf-8")
    if args.docs:
        write_docs(records, methods, Path(args.docs), summary)
    return 0


if __name__ == "__main__":
    sys.exit(main())
