"""Reconstruction on real measured materials, judged as a renderer sees them (issue 24).

Reads the neural-BRDF materials of ``../shared/realdata`` (never copied into the project): the 48 of
``nbrdf-merl`` and the 93 of ``nbrdf-extra`` (141: MERL, RGL-EPFL and Nielsen; ``--quick``: the 48 only), extracts
in-plane slices as a bench measures them (theta_o = -80..80 deg by 2 deg, the blind spot |theta_i + theta_o| < 4
deg left out; case ``1`` = one slice at 40 deg, ``2`` = 40/70 deg, ``3`` = 20/40/60 deg, or any ``A/B/...``),
reconstructs with each method, writes the MERL table and judges it against the material's own MERL table read
the same way (so the format's quantisation is not charged to the method) with
:func:`reconstruction.report.compare.judge`, what ``gonio-compare`` prints:

* **image**: PSNR of the tone-mapped renders of a sphere (key and rim lighting; the mean of the two) and the
  relative RMSE of the linear renders (``linear``), pixels seen at up to 80 deg;
* **cosl2**: relative cosine-weighted L2 of f over pairs drawn uniformly in solid angle (both angles <= 80 deg);
* **log**: mean |ln((f cos ti + 1e-3) / (f_true cos ti + 1e-3))| over the same pairs;
* **rmse80**: relative RMSE of f cos cos over the MERL cells within 80 deg, and the share of its square from
  theta_d >= 60 deg (``grazing``).

The **floor**, once per material: the material's own MERL table against the neural BRDF itself (image and pair
metrics). Methods: any of ``gonio-reconstruct``'s, ``auto+prior`` (auto with the prior), ``prior-local`` and
``auto+prior-local`` (the same with the local prior of the LOCAL_NEAR nearest materials, --prior-near), ``constant`` (a
constant f, the median of the samples: the baseline). ``prior`` and ``auto+prior`` complete each material from the prior
of the other materials of both folders (leave-one-out: a material never completes itself). Figures per case,
method and database; ``--docs DIR`` writes ``DIR/real-materials.md`` and the contact sheet
``DIR/real-materials.png`` (truth and reconstruction side by side, 1 and 2 slices). Usage::

    .venv/bin/python benchmarks/bench_real_materials.py [--quick] [--slices 1,2,3]
        [--methods auto,auto+prior,prior,constant] [--workers 2] [--docs docs] [--from-jsonl FILE]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings
from concurrent.futures import ProcessPoolExecutor, as_completed
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction import pipeline  # noqa: E402
from reconstruction.core import merlgrid, merltable  # noqa: E402
from reconstruction.core.checks import plausibility  # noqa: E402
from reconstruction.core.geometry import inplane_to_dirs  # noqa: E402
from reconstruction.core.metrics import IMAGE_MAX_VIEW_DEG, image_exposure, tone_map  # noqa: E402
from reconstruction.core.models import NBRDF_SUFFIXES, Material  # noqa: E402
from reconstruction.core.render import view_angle_mask  # noqa: E402
from reconstruction.core.slicedata import Slice  # noqa: E402
from reconstruction.methods import Options  # noqa: E402
from reconstruction.report import compare as cmp  # noqa: E402

MODES = {"1": (40.0,), "2": (40.0, 70.0), "3": (20.0, 40.0, 60.0)}
STEP_DEG, BLIND_DEG, MAX_DEG = 2.0, 4.0, 80.0
FOLDERS = ("nbrdf-merl", "nbrdf-extra")
DATABASES = ("MERL", "RGL", "Nielsen")
EXTRA_METHODS = ("auto+prior", "auto+prior-unbounded", "auto-unbounded", "constant", "prior-local", "auto+prior-local")
#: the local prior's basis (``prior-local``, ``auto+prior-local``: --prior-near, reconstruction.methods.prior_local)
LOCAL_NEAR = 20
DEFAULT_METHODS = "auto,auto+prior,prior,constant"
SHEET_MODES = ("1", "2")
ORACLE_METHODS = ("fit", "microfacet", "bivariate", "revolve", "prior")  # the summary's oracle: the best of these
SHEET_SIZE = 16  # materials on the contact sheet


def material_names(folder: Path) -> list[str]:
    """Every NAME with the six NAME_{fc1,b1,fc2,b2,fc3,b3}.npy files in ``folder``, sorted."""
    names = {p.name[: -len(f"_{NBRDF_SUFFIXES[0]}.npy")] for p in folder.glob(f"*_{NBRDF_SUFFIXES[0]}.npy")}
    return sorted(n for n in names if all((folder / f"{n}_{s}.npy").is_file() for s in NBRDF_SUFFIXES))


def database_of(folder: str, name: str) -> str:
    """MERL, RGL or Nielsen: nbrdf-merl is MERL; nbrdf-extra names start with merl-, rgl- or nielsen-."""
    if Path(folder).name == "nbrdf-merl" or name.startswith("merl-"):
        return "MERL"
    return "RGL" if name.startswith("rgl-") else "Nielsen" if name.startswith("nielsen-") else "other"


def incidences_of(mode: str) -> tuple[float, ...]:
    """The incidences (deg) of a case: ``1`` (40), ``2`` (40/70), ``3`` (20/40/60) or ``A/B/...`` (deg)."""
    if mode in MODES:
        return MODES[mode]
    try:
        inc = tuple(float(x) for x in mode.split("/"))
    except ValueError:
        raise ValueError(f"case {mode!r}: expected 1, 2, 3 or incidences in deg such as 20/50/75") from None
    if not inc or any(not 0.0 <= t <= MAX_DEG for t in inc):
        raise ValueError(f"case {mode!r}: incidences must lie in 0..{MAX_DEG:g} deg")
    return inc


def _label(mode: str) -> str:
    inc = incidences_of(mode)
    return f"{len(inc)} slice(s) at {'/'.join(f'{t:g}' for t in inc)} deg"


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


def _as_read(table: np.ndarray) -> np.ndarray:
    """A table as the truth's is read: NaN (a file's invalid marker) in the cells below the horizon."""
    return np.where(merlgrid.valid_mask()[None], table, np.nan)


def material_truth(name: str, folder: str | Path, cache: str | Path | None) -> tuple[Any, np.ndarray]:
    """(the material ``name`` of ``folder`` as a model, its MERL table as the truth's is read: :func:`_as_read`),
    the table tabulated once and kept as float32 in ``cache`` (a folder; None: not kept)."""
    mat = Material.from_dict({"name": name, "lobes": [{"type": "nbrdf", "path": str(Path(folder) / name)}]})
    cached = Path(cache) / f"{name}.npy" if cache else None
    if cached is not None and cached.is_file():
        truth = np.load(cached).astype(np.float64)
    else:
        truth = merltable.tabulate(mat.eval)
        if cached is not None:
            cached.parent.mkdir(parents=True, exist_ok=True)
            np.save(cached, truth.astype(np.float32))
    return mat, _as_read(truth)


def _reconstruct(method: str, s: Slice, prior: str | None, name: str, shared: dict[str, Any] | None = None
                 ) -> tuple[np.ndarray, dict[str, Any]]:
    """(table, facts) of one method on the slices ``s``; ``prior`` leaves ``name`` out. ``shared``: a dict kept
    for one material and case, in which a method and its ``-unbounded`` variant share one reconstruction (the
    second's ``seconds`` fact is the first's reconstruction time plus its own)."""
    if method == "constant":
        c = np.median(s.values.reshape(len(s), -1), axis=0)
        c = np.repeat(c, 3) if c.size == 1 else c
        return np.broadcast_to(c[:, None, None, None], merltable.SHAPE).copy(), {"used": "constant"}
    with_prior = method in ("prior", "auto+prior", "auto+prior-unbounded", "prior-local", "auto+prior-local")
    opts = Options(prior=prior if with_prior else None, prior_exclude=(name,) if with_prior else (),
                            prior_near=LOCAL_NEAR if method.endswith("-local") else 0)
    base = method.removesuffix("-unbounded")
    facts: dict[str, Any] = {}
    t0 = time.perf_counter()
    if shared is not None and base in shared:
        rec, choice, table, took = shared[base]
        facts["shared_reconstruction"] = True
    else:
        rec, choice = pipeline.reconstruct(s, "auto" if method.startswith("auto") else method.removesuffix("-local"),
                                           opts)
        table = pipeline.tabulate(rec)
        took = time.perf_counter() - t0
        if shared is not None:
            shared[base] = (rec, choice, table, took)
        t0 = time.perf_counter()
    if method in ("auto", "auto+prior", "auto+prior-local"):  # as gonio-reconstruct writes auto's table
        # (-unbounded: --no-conservative)
        rec, table, bounded, _ = pipeline.bound_where_unmeasured(rec, table, s, opts)
        facts["cells_lowered"] = bounded["cells_lowered"]
        facts["energy_removed"] = bounded["energy_removed"]
    facts["seconds"] = took + (time.perf_counter() - t0)
    checks = plausibility(rec, table)
    facts.update({"used": choice["used"], "plausible": bool(checks["all_pass"]),
                  "max_albedo": float(checks["albedo"]["max"])})
    if "cross_validation" in choice:
        facts["chosen_label"] = choice["cross_validation"].get("chosen_label", choice["used"])
    return table, facts


def _figures(res: dict[str, Any]) -> dict[str, float]:
    im = res["image"]
    out = {"psnr_db": im["psnr_db"], "linear": im["relative_rmse"],
           "linear_but_brightest": im["relative_rmse_but_brightest_pixel"], "cosl2": res["cosl2"],
           "log": res["log_error"]}
    for light in cmp.LIGHTINGS:
        out[f"psnr_{light}_db"] = im[light]["psnr_db"]
        out[f"linear_{light}"] = im[light]["relative_rmse"]
        out[f"linear_{light}_but_brightest"] = im[light]["relative_rmse_but_brightest_pixel"]
    if "rmse80" in res:
        out["rmse80"], out["grazing"] = res["rmse80"], res["rmse80_grazing_share"]
    return out


def _display(images: dict[str, np.ndarray], truth: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """uint8 tone-mapped renders (the truth's exposure per lighting), for the contact sheet."""
    out = {}
    for light in cmp.LIGHTINGS:
        e = image_exposure(truth[light], view_angle_mask(truth[light].shape[0], 1.0, IMAGE_MAX_VIEW_DEG))
        out[light] = np.round(tone_map(images[light], e) * 255).astype(np.uint8)
    return out


def run_material(job: dict[str, Any]) -> dict[str, Any]:
    """Worker: one material's floor and every (case, method); records, the floor and the sheet's images."""
    warnings.simplefilter("ignore")
    from threadpoolctl import threadpool_limits

    name, folder, size = job["name"], job["folder"], job["size"]
    db = database_of(folder, name)
    with threadpool_limits(1), np.errstate(all="ignore"):
        cache = Path(job["cache"]) if job["cache"] else None
        mat, truth = material_truth(name, folder, cache)
        tb = cmp.Brdf(name, "merl", merltable.brdf_of(truth), truth)
        ref = cmp.reference(tb, size)
        floor_file = cache / f"{name}.floor-{size}.json" if cache else None
        if floor_file is not None and floor_file.is_file():
            floor = json.loads(floor_file.read_text())
        else:  # the format's own error: the truth's table against the neural BRDF itself
            floor = _figures(cmp.judge(tb, cmp.reference(cmp.Brdf(name, "nbrdf", mat.eval), size), False))
            if floor_file is not None:
                floor_file.write_text(json.dumps(floor))
        floor.update(material=name, database=db)
        out: dict[str, Any] = {"records": [], "floor": floor, "images": {}}
        if job["sheet"]:
            out["images"]["truth"] = _display(ref.images, ref.images)
        for mode in job["modes"]:
            s = slices_of(mat, incidences_of(mode))
            shared: dict[str, Any] = {}  # auto and auto-unbounded: one reconstruction
            for m in job["methods"]:
                rec: dict[str, Any] = {"material": name, "database": db, "slices": mode, "method": m}
                t0 = time.perf_counter()
                try:
                    table, facts = _reconstruct(m, s, job["prior"], name, shared)
                    rec["seconds"] = facts.pop("seconds", time.perf_counter() - t0)
                    rec.update(facts)
                    a = cmp.Brdf(m, "merl", merltable.brdf_of(_as_read(table)), _as_read(table))
                    imgs = cmp.render_images(a, size)
                    rec.update(_figures(cmp.judge(a, ref, images=imgs)))
                    if job["sheet"] and mode in SHEET_MODES and m == job["sheet_method"]:
                        out["images"][mode] = _display(imgs, ref.images)
                except Exception as e:  # a benchmark reports a failure and goes on
                    rec.update(error=f"{type(e).__name__}: {e}", seconds=time.perf_counter() - t0)
                out["records"].append(rec)
    return out


# --- the summary ------------------------------------------------------------------------------------------------


def _stats(rs: list[dict[str, Any]]) -> dict[str, float]:
    p = np.array([r["psnr_db"] for r in rs])
    p = np.where(np.isfinite(p), p, 99.0)
    lin = np.array([r["linear"] for r in rs]) * 100
    out = {"n": len(rs), "psnr_median": float(np.median(p)), "psnr_worst": float(p.min()),
           "linear_median": float(np.median(lin)), "linear_worst": float(lin.max()),
           "worst_material": rs[int(np.argmin(p))]["material"]}
    for k in ("cosl2", "log", "rmse80", "grazing"):
        if all(k in r for r in rs):
            v = np.array([r[k] for r in rs]) * (1 if k == "log" else 100)
            out[f"{k}_median"], out[f"{k}_worst"] = float(np.median(v)), float(v.max())
    return out


def _line(label: str, st: dict[str, float]) -> str:
    s = (f"{label:24s} PSNR median {st['psnr_median']:5.1f} / worst {st['psnr_worst']:5.1f} dB "
         f"({st['worst_material']}); linear {st['linear_median']:5.1f} / {st['linear_worst']:6.1f} %")
    if "cosl2_median" in st:
        s += f"; cosl2 {st['cosl2_median']:5.1f} / {st['cosl2_worst']:6.1f} %; log {st['log_median']:.3f}"
    if "rmse80_median" in st:
        s += f"; rmse80 {st['rmse80_median']:5.1f} % ({st['grazing_median']:.0f} % at theta_d >= 60)"
    return s + f" [{st['n']}]"


def summarise(records: list[dict[str, Any]], floors: list[dict[str, Any]], methods: list[str]) -> list[str]:
    """Lines: the floor, then per case and method (all materials, then per database) the image metrics (PSNR
    median / worst material, linear error median / worst), cosl2, log and rmse80 medians; failures counted."""
    lines = []
    if floors:
        lines.append("floor (the truth's own MERL table against the neural BRDF):")
        lines.append("  " + _line("all", _stats(floors)))
        for db in DATABASES:
            fs = [f for f in floors if f["database"] == db]
            if fs:
                lines.append("  " + _line(db, _stats(fs)))
    for mode in dict.fromkeys(r["slices"] for r in records):
        lines.append(f"{_label(mode)}:")
        for m in methods:
            rs = [r for r in records if r["slices"] == mode and r["method"] == m]
            ok = [r for r in rs if "psnr_db" in r]
            if not ok:
                lines.append(f"  {m:11s} no result")
                continue
            st = _stats(ok)
            bad = sum(1 for r in ok if r["linear"] > 0.5)
            but = [r for r in ok if "linear_but_brightest" in r]  # records of an older run may lack it
            bad_but = (f" ({sum(1 for r in but if r['linear_but_brightest'] > 0.5)} without the truth's brightest "
                       f"pixel)" if len(but) == len(ok) else "")
            implausible = sum(1 for r in ok if not r.get("plausible", True))
            extra = (f"; linear > 50 %: {bad}{bad_but}; implausible: {implausible}"
                     f"; failed: {len(rs) - len(ok)}; time median {np.median([r['seconds'] for r in ok]):.2f} s")
            lines.append("  " + _line(m, st) + extra)
            for db in DATABASES:
                dr = [r for r in ok if r.get("database") == db]
                if dr and len(dr) < len(ok):
                    lines.append("    " + _line(db, _stats(dr)))
        lines += _oracle_lines([r for r in records if r["slices"] == mode], methods)
    return lines


def _oracle_lines(rs: list[dict[str, Any]], methods: list[str]) -> list[str]:
    """With two or more single methods in the run: per material the best of them by PSNR, chosen with the truth
    (what no selection among them can beat), its median and worst."""
    single = [m for m in methods if m in ORACLE_METHODS]
    if len(single) < 2:
        return []
    best: dict[str, float] = {}
    for r in rs:
        if r["method"] in single and "psnr_db" in r:
            best[r["material"]] = max(best.get(r["material"], -np.inf), float(r["psnr_db"]))
    if not best:
        return []
    v = np.array(list(best.values()))
    return [f"  {'oracle':11s} the best of {', '.join(single)} per material, chosen with the truth: PSNR median "
            f"{np.median(v):5.1f} / worst {v.min():5.1f} dB [{v.size}]"]


# --- the docs page and the contact sheet ------------------------------------------------------------------------

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


def sheet_materials(names_by_db: dict[str, list[str]], n: int = SHEET_SIZE) -> list[str]:
    """``n`` materials spread over the databases (in proportion, at least one of each present) and over each
    database's sorted names."""
    total = sum(len(v) for v in names_by_db.values())
    out: list[str] = []
    for names in names_by_db.values():
        if not names:
            continue
        k = max(1, round(n * len(names) / max(total, 1)))
        idx = np.unique(np.linspace(0, len(names) - 1, min(k, len(names))).round().astype(int))
        out += [names[i] for i in idx]
    return out


def write_sheet(path: Path, images: dict[str, dict[str, dict[str, np.ndarray]]],
                records: list[dict[str, Any]], method: str) -> None:
    """The contact sheet: per material (a row) the truth and the reconstruction from 1 and 2 slices, key and rim
    lighting, each reconstruction labelled with its PSNR and linear error."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    names = [n for n in images if "truth" in images[n]]
    cols = [("truth", "key"), *((m, "key") for m in SHEET_MODES), ("truth", "rim"), *((m, "rim") for m in SHEET_MODES)]
    fig, axes = plt.subplots(len(names), len(cols), figsize=(1.45 * len(cols), 1.6 * len(names)), squeeze=False)
    by = {(r["material"], r["slices"]): r for r in records if r["method"] == method and "psnr_db" in r}
    for row, n in zip(axes, names, strict=True):
        for ax, (what, light) in zip(row, cols, strict=True):
            ax.axis("off")
            img = images[n].get(what, {}).get(light)
            if img is None:
                continue
            ax.imshow(img, interpolation="nearest")
            if what == "truth":
                ax.set_title(f"{n[:24]}\ntruth ({light})", fontsize=6)
            else:
                r = by.get((n, what))
                fig_txt = (f"{r[f'psnr_{light}_db']:.1f} dB, {r[f'linear_{light}'] * 100:.0f} %" if r else "")
                ax.set_title(f"{what} slice(s) ({light})\n{fig_txt}", fontsize=6)
    fig.suptitle(f"{method}: truth and reconstruction from 1 slice (40 deg) and 2 slices (40/70 deg)", fontsize=9)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.4 / fig.get_figheight()))  # room for the title
    fig.savefig(path, dpi=90)
    plt.close(fig)


def _table(records: list[dict[str, Any]], methods: list[str], modes: list[str]) -> list[str]:
    rows = ["| case | method | PSNR median / worst (dB) | linear error median / worst | cosl2 median / worst | "
            "log median | rmse80 median (share at theta_d >= 60) | MERL / RGL / Nielsen PSNR median (worst) |",
            "|---|---|---|---|---|---|---|---|"]
    for mode in modes:
        for m in methods:
            ok = [r for r in records if r["slices"] == mode and r["method"] == m and "psnr_db" in r]
            if not ok:
                continue
            st = _stats(ok)
            dbs = []
            for db in DATABASES:
                dr = [r for r in ok if r.get("database") == db]
                dbs.append(f"{_stats(dr)['psnr_median']:.1f} ({_stats(dr)['psnr_worst']:.1f})" if dr else "-")
            rows.append(f"| {_label(mode)} | {m} | {st['psnr_median']:.1f} / {st['psnr_worst']:.1f} | "
                        f"{st['linear_median']:.0f} % / {st['linear_worst']:.0f} % | "
                        f"{st.get('cosl2_median', np.nan):.0f} % / {st.get('cosl2_worst', np.nan):.0f} % | "
                        f"{st.get('log_median', np.nan):.3f} | {st.get('rmse80_median', np.nan):.0f} % "
                        f"({st.get('grazing_median', np.nan):.0f} %) | {' / '.join(dbs)} |")
    return rows


def write_docs(records: list[dict[str, Any]], floors: list[dict[str, Any]], methods: list[str], docs: Path,
               summary: list[str], command: str, images: dict[str, Any] | None = None,
               sheet_method: str = "auto+prior") -> None:
    """docs/real-materials.md (led by the image metric and the contact sheet) and, with ``images``, the sheet
    docs/real-materials.png; the page's hand-written notes block (:func:`kept_notes`) is kept."""
    docs.mkdir(parents=True, exist_ok=True)
    modes = list(dict.fromkeys(r["slices"] for r in records))
    if images:
        write_sheet(docs / "real-materials.png", images, records, sheet_method)
    n_mat = len({r["material"] for r in records})
    fl = _stats(floors) if floors else None
    floor_txt = (f"The floor, the materials' own MERL tables against the neural BRDFs themselves: PSNR median "
                 f"{fl['psnr_median']:.1f} dB, worst {fl['psnr_worst']:.1f} dB ({fl['worst_material']}); linear "
                 f"error median {fl['linear_median']:.1f} %." if fl else "")
    per = ["| material | database | " + " | ".join(f"{m} ({mode})" for mode in modes for m in methods) + " |",
           "|---|---|" + "---|" * (len(methods) * len(modes))]
    for n in sorted({r["material"] for r in records}):
        cells = []
        for mode in modes:
            for m in methods:
                r = next((r for r in records if r["material"] == n and r["slices"] == mode and r["method"] == m),
                         None)
                if r is None or "psnr_db" not in r:
                    cells.append("failed" if r else "")
                else:
                    used = f" [{r.get('chosen_label', r.get('used', ''))}]" if m.startswith("auto") else ""
                    cells.append(f"{r['psnr_db']:.1f} / {r['linear'] * 100:.0f} %{used}")
        db = next(r.get("database", "") for r in records if r["material"] == n)
        per.append(f"| {n} | {db} | " + " | ".join(cells) + " |")
    text = f"""# Real materials, judged as a renderer sees them

Regenerate: `{command}` (reads `../shared/realdata`, which is not part of the project). It rewrites this page
and the contact sheet except the block of notes, which is written by hand and names the command of every figure
it quotes that this benchmark does not print.

**Image metric.** A sphere rendered with the reconstruction's MERL table and with the material's own MERL table
(read the same way: trilinear lookups, so the format's quantisation is not charged to the method), under a
sky-and-ground environment plus a key sun in front and, in a second image, a rim sun behind the sphere (grazing
light); pixels seen at more than 80 deg left out. **PSNR** of the tone-mapped images (exposure at the truth's
99.5th percentile, clipped, gamma 2.2; the mean of the key and rim images) and the relative RMSE of the **linear**
images (the energy errors that tone mapping clips). On a glossy sphere the linear error is its highlight's one
or two brightest pixels, whose value is f at a theta_h finer than the slices' 2 deg step; the summary also counts
the tables above 50 % with the truth's brightest pixel of each image left out. `gonio-compare A B` prints the same
figures for any two BRDFs.

{n_mat} materials of `../shared/realdata` (neural-BRDF fits of MERL, RGL-EPFL and Nielsen measurements), sliced
as a bench measures them: theta_o from -80 to 80 deg every 2 deg, the blind spot |theta_i + theta_o| < 4 deg
left out. `prior` and `auto+prior` complete each material from a prior of the **other** materials of the run
(leave-one-out; both folders, or the 48 of `nbrdf-merl` with `--quick`); `auto` runs without a prior;
`constant` is a constant f (the median of the samples), the baseline. {floor_txt}

{chr(10).join(_table(records, methods, modes))}

![Truth and reconstruction side by side: key and rim lighting, 1 slice at 40 deg and 2 at 40/70 deg]
(real-materials.png)

*The contact sheet: per material the truth, then `{sheet_method}` from 1 slice (40 deg) and 2 slices (40/70 deg),
under the key (left three) and the rim light (right three), tone-mapped with the truth's exposure; each
reconstruction's PSNR and linear error under it.*

The other figures: **cosl2**, the relative cosine-weighted L2 of f over direction pairs drawn uniformly in solid
angle with both angles <= 80 deg; **log**, mean |ln((f cos theta_i + 1e-3) / (f_true cos theta_i + 1e-3))| over
the same pairs; **rmse80**, the relative RMSE of f cos theta_i cos theta_o over the MERL cells within 80 deg, a
stress test of grazing theta_d (the share of its square from theta_d >= 60 deg in brackets).

## Summary

```
{chr(10).join(summary)}
```

## Reading the figures

{kept_notes(docs / "real-materials.md")}

## Every material (PSNR dB / linear image error; `[method]`: what auto chose)

{chr(10).join(per)}
"""
    (docs / "real-materials.md").write_text(text.replace("]\n(real-materials.png)", "](real-materials.png)"),
                                            encoding="utf-8")


# --- the command ------------------------------------------------------------------------------------------------


def _sheet_dir(jsonl: Path) -> Path:
    """Where a run keeps the contact sheet's renders (beside its records), one npz per material."""
    return jsonl.with_name(jsonl.stem + "-sheet")


def _save_images(folder: Path, name: str, images: dict[str, dict[str, np.ndarray]]) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    np.savez_compressed(folder / f"{name}.npz", **{f"{k}__{light}": v for k, d in images.items()
                                                    for light, v in d.items()})


def _load_images(folder: Path) -> dict[str, dict[str, dict[str, np.ndarray]]]:
    out: dict[str, dict[str, dict[str, np.ndarray]]] = {}
    for p in sorted(folder.glob("*.npz")) if folder.is_dir() else []:
        with np.load(p) as z:
            for key in z.files:
                what, light = key.split("__")
                out.setdefault(p.stem, {}).setdefault(what, {})[light] = z[key]
    return out


def _load_jsonl(path: Path) -> tuple[list[dict[str, Any]], list[dict[str, Any]]]:
    recs, floors = [], []
    for line in path.read_text(encoding="utf-8").splitlines():
        if line.strip():
            r = json.loads(line)
            (floors if r.get("kind") == "floor" else recs).append(r)
    return recs, floors


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "realdata"),
                    help="the real-data folder (with nbrdf-merl/ and nbrdf-extra/); default ../shared/realdata")
    ap.add_argument("--quick", action="store_true", help="the 48 materials of nbrdf-merl only (the development set)")
    ap.add_argument("--materials", help="comma-separated material names (default: all)")
    ap.add_argument("--methods", default=DEFAULT_METHODS,
                    help=f"comma-separated: {', '.join(pipeline.METHODS + EXTRA_METHODS)} (default {DEFAULT_METHODS})")
    ap.add_argument("--slices", default="1,2,3",
                    help="cases, comma-separated: 1 (40 deg), 2 (40/70), 3 (20/40/60) or A/B/... in deg; default 1,2,3")
    ap.add_argument("--workers", type=int, default=min(2, os.cpu_count() or 1), help="worker processes")
    ap.add_argument("--size", type=int, default=128, help="image size (pixels)")
    ap.add_argument("--cache", default=str(ROOT / "out" / "real-materials-cache"),
                    help="folder for the materials' own tables and floors (computed once); '' for none")
    ap.add_argument("--prior", default=None, metavar="DIRS",
                    help=f"prior folders joined by '{os.pathsep}' (default: the data's folders, leave-one-out); '' "
                         "for none")
    ap.add_argument("--docs", metavar="DIR", help="write DIR/real-materials.md and the contact sheet")
    ap.add_argument("--sheet-method", default="auto+prior", help="the method shown on the contact sheet")
    ap.add_argument("--jsonl", default=str(ROOT / "out" / "real-materials.jsonl"),
                    help="every record, one per line, written as they come")
    ap.add_argument("--from-jsonl", metavar="FILE", help="summarise (and --docs) the records of FILE; run nothing")
    args = ap.parse_args(argv)
    methods = [m.strip() for m in args.methods.split(",") if m.strip()]
    bad = [m for m in methods if m not in pipeline.METHODS + EXTRA_METHODS]
    modes = [m.strip() for m in args.slices.split(",") if m.strip()]
    try:
        for m in modes:
            incidences_of(m)
    except ValueError as e:
        print(f"bench_real_materials: --slices: {e}", file=sys.stderr)
        return 2
    if bad:
        print(f"bench_real_materials: unknown method(s) {bad}; expected {', '.join(pipeline.METHODS + EXTRA_METHODS)}",
              file=sys.stderr)
        return 2
    given = list(argv if argv is not None else sys.argv[1:])
    kept = [a for k, a in enumerate(given) if not a.startswith("--from-jsonl")
            and not (k > 0 and given[k - 1] == "--from-jsonl")]
    command = ".venv/bin/python benchmarks/bench_real_materials.py " + " ".join(kept)
    if args.from_jsonl:
        records, floors = _load_jsonl(Path(args.from_jsonl))
        methods = [m for m in methods if any(r["method"] == m for r in records)]
        summary = summarise(records, floors, methods)
        print("\n".join(summary))
        if args.docs:
            write_docs(records, floors, methods, Path(args.docs), summary, command.strip(),
                       _load_images(_sheet_dir(Path(args.from_jsonl))), args.sheet_method)
        return 0
    data = Path(args.data)
    folders = [data / f for f in (FOLDERS[:1] if args.quick else FOLDERS) if (data / f).is_dir()]
    if not folders:
        print(f"bench_real_materials: {data}/nbrdf-merl not found (see ../shared/realdata/README.md)", file=sys.stderr)
        return 2
    where = {n: str(f) for f in folders for n in material_names(f)}
    names = sorted(where)
    if args.materials:
        want = [n.strip() for n in args.materials.split(",") if n.strip()]
        missing = sorted(set(want) - set(names))
        if missing:
            print(f"bench_real_materials: unknown material(s) {missing}", file=sys.stderr)
            return 2
        names = want
    prior = os.pathsep.join(str(f) for f in folders) if args.prior is None else (args.prior or None)
    if any(m in ("prior", "auto+prior", "prior-local", "auto+prior-local") for m in methods):
        if not prior:
            print("bench_real_materials: prior and auto+prior need a prior (--prior)", file=sys.stderr)
            return 2
        from reconstruction.methods.prior import load_prior

        load_prior(prior)  # tabulated once (and cached) before the workers start
    by_db: dict[str, list[str]] = {}
    for n in names:
        by_db.setdefault(database_of(where[n], n), []).append(n)
    sheet = set(sheet_materials(by_db)) if args.docs else set()
    sheet_dir = _sheet_dir(Path(args.jsonl))
    if sheet_dir.is_dir():
        for old in sheet_dir.glob("*.npz"):
            old.unlink()
    names = sorted(names, key=lambda n: n not in sheet)  # the sheet's materials first: a partial run shows them
    jobs = [{"name": n, "folder": where[n], "methods": methods, "modes": modes, "prior": prior, "cache": args.cache,
             "size": args.size, "sheet": n in sheet, "sheet_method": args.sheet_method} for n in names]
    from tqdm import tqdm

    records: list[dict[str, Any]] = []
    floors: list[dict[str, Any]] = []
    images: dict[str, Any] = {}
    t0 = time.perf_counter()
    Path(args.jsonl).parent.mkdir(parents=True, exist_ok=True)
    with open(args.jsonl, "w", encoding="utf-8") as log, \
            ProcessPoolExecutor(max_workers=max(1, args.workers)) as ex:
        futures = {ex.submit(run_material, j): j["name"] for j in jobs}
        for fut in tqdm(as_completed(futures), total=len(jobs), desc="materials", file=sys.stderr):
            out = fut.result()
            floors.append(out["floor"])
            log.write(json.dumps({"kind": "floor", **out["floor"]}) + "\n")
            if out["images"]:
                images[futures[fut]] = out["images"]
                _save_images(sheet_dir, futures[fut], out["images"])
            for r in out["records"]:
                records.append(r)
                log.write(json.dumps(r) + "\n")
                if "psnr_db" in r:
                    used = f" [{r.get('chosen_label', r.get('used'))}]" if r["method"].startswith("auto") else ""
                    print(f"{r['material']:34s} {r['slices']:>3s} {r['method']:11s} PSNR {r['psnr_db']:5.1f} dB "
                          f"linear {r['linear'] * 100:6.1f} % cosl2 {r['cosl2'] * 100:6.1f} % log {r['log']:.3f} "
                          f"rmse80 {r['rmse80'] * 100:6.1f} %  {r['seconds']:5.2f} s{used}", flush=True)
                else:
                    print(f"{r['material']:34s} {r['slices']:>3s} {r['method']:11s} FAILED: {r['error']}", flush=True)
            log.flush()
    summary = summarise(records, floors, methods)
    summary.append(f"{len(names)} materials, {len(records)} reconstructions, {time.perf_counter() - t0:.0f} s "
                   f"wall with {args.workers} worker(s)")
    print("\n".join(summary))
    if args.docs:
        write_docs(records, floors, methods, Path(args.docs), summary, command.strip(),
                   {n: images[n] for n in sorted(images)}, args.sheet_method)
    return 0


if __name__ == "__main__":
    sys.exit(main())
