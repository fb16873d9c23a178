"""Beyond the linear prior (issue 40): each candidate prior's floor and its reconstruction, judged by the image.

Candidates (leave-one-out over the 141 materials of ``../shared/realdata``, a prior of the other 140):

* ``linear``: today's ``prior`` (:mod:`reconstruction.methods.prior`), one PCA basis of every other material;
* ``local``: the same model with a basis of the ``n_near`` materials nearest to the sample at its cells
  (:mod:`reconstruction.methods.prior_local`, :func:`reconstruct_local`);
* ``structured``: factors (diffuse/retro over theta_d, microfacet distribution over theta_h, Fresnel-like factor
  over theta_d) with a Gaussian prior over them (:mod:`reconstruction.methods.prior_structured`);
* ``blend``: the kernel-weighted mean of the nearest prior rows, no linear space (:func:`reconstruct_blend`).

Per material and case (1 slice at 40 deg, 2 at 40/70, 3 at 20/40/60; the slices of bench_real_materials.py):

* the **floor** of each candidate, the protocol of bench_prior_floor.py ``--image``: the model fitted to the
  material's own exact values at the reduced-grid cells the slices touch, its hyper-parameters chosen with the truth
  by the PSNR of 64-pixel renders, the chosen one's PSNR from 128-pixel renders. Grids: linear K 5/10/20/30 x ridge
  0.1/1/10 (bench_prior_floor.py's); local n_near 10/20/40 x K 5/10/20 (ridge 1); structured lam 0.003/0.03/0.3;
  blend n_near 1/4/8 x tau 0.3/1. ``structured-all``: the material's own factors fitted to all its cells (no
  prior: what the factor model can represent at all);
* the **reconstruction** from the slices' samples with each candidate's fixed defaults (none chosen with the truth),
  PSNR from 128-pixel renders as bench_real_materials.py judges (the truth's MERL table read the same way).

Today's ``auto+prior`` for comparison is read from the per-material table of docs/real-materials.md (the last
bench_real_materials.py run, same slices, same renders). Usage::

    .venv/bin/python benchmarks/bench_prior_candidates.py [--every 3] [--offset 0] [--slices 1,2,3]
        [--workers 1] [--jsonl out/prior-candidates.jsonl] [--from-jsonl FILE]

About 30 s of CPU per material for the three cases on an idle core (4301 s for the 141), two to five times that
on a busy machine; ``--every 1 --workers 2``: the 141 in about 36 min (docs/real-materials.md's run).
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

import bench_real_materials as BR  # noqa: E402

from reconstruction.methods import prior as P  # noqa: E402
from reconstruction.methods import prior_local as L  # noqa: E402
from reconstruction.methods import prior_structured as S  # noqa: E402

CANDIDATES = ("linear", "local", "structured", "blend")
LIN_K, LIN_LAM = (5, 10, 20, 30), (0.1, 1.0, 10.0)
LOC_N, LOC_K, LOC_LAM = (10, 20, 40), (5, 10, 20), (1.0,)
STR_LAM = (0.003, 0.03, 0.3)
BLEND_N, BLEND_TAU = (1, 4, 8), (0.3, 1.0)
STATE: dict[str, Any] = {}  # the prior and its factors, set before the workers fork


def _psnr(rec: P.PriorReconstruction, ref: Any) -> float:
    from reconstruction.core import merltable
    from reconstruction.report import compare as cmp

    t = BR._as_read(rec.table())
    imgs = cmp.render_images(cmp.Brdf("rec", "merl", merltable.brdf_of(t), t), ref.size)
    return float(cmp.image_metrics(imgs, ref.images, ref.size)["psnr_db"])


def _rec(mapped: np.ndarray, scale: np.ndarray) -> P.PriorReconstruction:
    """A reduced-grid reconstruction from mapped values (3, M) at the training cells and scales (3,)."""
    g = P._grid()
    f = np.zeros((mapped.shape[0], g["cos"].size))
    f[:, g["train"]] = np.maximum(np.exp(mapped) - P.EPS, 0.0) * scale[:, None] / g["cos"][g["train"]]
    return P.PriorReconstruction(["R", "G", "B"], np.where(g["cos"] > 0, P._extend(f), 0.0), {})


def _linear_fits(mu: np.ndarray, comps: np.ndarray, sig: np.ndarray, y: np.ndarray, obs: np.ndarray,
                 ks: tuple[int, ...], lams: tuple[float, ...]) -> list[np.ndarray]:
    """Mapped fits (3, M) of the basis to ``y`` (3, M) at cells ``obs`` for every K and ridge weight."""
    out = []
    for k in ks:
        k = min(k, comps.shape[0])
        a = comps[:k, obs].T
        gram, rhs = a.T @ a, a.T @ (y[:, obs] - mu[obs]).T
        for lam in lams:
            coef = np.linalg.solve(gram + lam * np.diag(1.0 / sig[:k] ** 2), rhs)
            out.append(coef.T @ comps[:k] + mu)
    return out


def _best(cands: list[np.ndarray], scale: np.ndarray, small: Any, full: Any) -> float:
    """The floor: the candidate with the best 64-pixel PSNR, judged at 128 pixels."""
    best = max(cands, key=lambda m: _psnr(_rec(m, scale), small))
    return _psnr(_rec(best, scale), full)


def floors(name: str, incs: tuple[float, ...], small: Any, full: Any) -> dict[str, float]:
    """Every candidate's floor for material ``name`` and slices at ``incs`` (deg)."""
    ps: P.PriorSet = STATE["ps"]
    sp: S.StructuredPrior = STATE["sp"]
    m = ps.names.index(name)
    s = _positions(incs)
    idx, w, _ = P._design(s)
    obs_mask = np.zeros(int(P._grid()["train"].sum()), bool)
    obs_mask[np.unique(idx[w > 0.05])] = True
    obs = np.flatnonzero(obs_mask)
    fc = ps._fc()[3 * m:3 * m + 3].astype(np.float64)
    scale = P.channel_scales(np.einsum("nj,cnj->cn", w, fc[:, idx]))
    y = np.log(fc / scale[:, None] + P.EPS)  # (3, M) the truth, mapped
    out: dict[str, float] = {}
    mu, comps, sig = ps.basis(idx, w, exclude=(name,))
    out["linear"] = _best(_linear_fits(mu, comps, sig, y, obs, LIN_K, LIN_LAM), scale, small, full)
    keep = [i for i, n in enumerate(ps.names) if n != name]
    rows_full = None
    fc_all = ps._fc()
    rscale = P.channel_scales(np.einsum("nj,tnj->tn", w, fc_all[:, idx]).reshape(len(ps.names), 3, -1)).reshape(-1)
    rows_keep = (np.asarray(keep)[:, None] * 3 + np.arange(3)).ravel()
    rows_obs = np.log(fc_all[rows_keep][:, obs] / rscale[rows_keep, None] + P.EPS)  # (T, |obs|)
    d = L.row_distances(y[:, obs], rows_obs).reshape(3, len(keep), 3).min(axis=2).mean(axis=0)
    order = [ps.names[keep[i]] for i in np.argsort(d, kind="stable")]
    cands = []
    for n_near in LOC_N:
        near = set(order[:n_near])
        mu, comps, sig = ps.basis(idx, w, exclude=tuple(n for n in ps.names if n not in near))
        cands += _linear_fits(mu, comps, sig, y, obs, LOC_K, LOC_LAM)
    out["local"] = _best(cands, scale, small, full)
    ft = S.grid_features().take(obs)
    gauss = sp.gaussian((name,), ft)
    cands = []
    for lam in STR_LAM:
        pr = np.stack([S.map_factors(y[c, obs], ft, gauss, lam) for c in range(3)])
        cands.append(np.stack([S.model_mapped(p, S.grid_features()) for p in pr]))
    out["structured"] = _best(cands, scale, small, full)
    dd = L.row_distances(y[:, obs], rows_obs)
    chosen = np.unique(np.argsort(dd, axis=1)[:, :max(BLEND_N)])
    rows_full = np.log(fc_all[rows_keep[chosen]].astype(np.float64) / rscale[rows_keep[chosen], None] + P.EPS)
    cands = [L.blend_mapped(y[:, obs], rows_obs[chosen], rows_full, n, tau) for n in BLEND_N for tau in BLEND_TAU]
    out["blend"] = _best(cands, scale, small, full)
    return out


def _positions(incs: tuple[float, ...]) -> Any:
    from reconstruction.core.slicedata import Slice

    to = np.arange(-BR.MAX_DEG, BR.MAX_DEG + 1e-9, BR.STEP_DEG)
    a = np.concatenate([np.full(int(np.sum(np.abs(to + t) >= BR.BLIND_DEG)), t) for t in incs])
    b = np.concatenate([to[np.abs(to + t) >= BR.BLIND_DEG] for t in incs])
    return Slice(a, b, np.ones((a.size, 1)), ["value"])


def DEFAULT_RECS(s: Any, ps: P.PriorSet, name: str) -> dict[str, Any]:  # noqa: N802
    """The candidates' reconstructions with their defaults, each a function of no argument."""
    return {"linear": lambda: P.reconstruct_prior(s, ps, exclude=(name,)),
            "local": lambda: L.reconstruct_local(s, ps, exclude=(name,)),
            "structured": lambda: S.reconstruct_structured(s, STATE["sp"], exclude=(name,)),
            "blend": lambda: L.reconstruct_blend(s, ps, exclude=(name,))}


def DEV_RECS(s: Any, ps: P.PriorSet, name: str) -> dict[str, Any]:  # noqa: N802
    """``--dev``: the candidates' reconstructions for a grid of their defaults (to choose them on materials the
    evaluation leaves out)."""
    out: dict[str, Any] = {"linear": lambda: P.reconstruct_prior(s, ps, exclude=(name,))}
    for n in DEV_NEAR:
        out[f"local-{n}"] = lambda n=n: L.reconstruct_local(s, ps, exclude=(name,), n_near=n)
    for lam in DEV_LAM:
        out[f"structured-{lam:g}"] = lambda lam=lam: S.reconstruct_structured(s, STATE["sp"], exclude=(name,), lam=lam)
    for n, tau in DEV_BLEND:
        out[f"blend-{n}-{tau:g}"] = lambda n=n, tau=tau: L.reconstruct_blend(s, ps, exclude=(name,), n_near=n, tau=tau)
    return out


DEV_NEAR, DEV_LAM, DEV_BLEND = (10, 20, 30, 45), (0.01, 0.03, 0.1, 0.3), ((4, 0.3), (8, 0.3), (16, 1.0))


def run_material(job: dict[str, Any]) -> dict[str, Any]:
    """Worker: one material's floors and reconstructions per case."""
    from threadpoolctl import threadpool_limits

    from reconstruction.core import merltable
    from reconstruction.core.models import Material
    from reconstruction.report import compare as cmp

    warnings.simplefilter("ignore")
    name, folder = job["name"], job["folder"]
    ps: P.PriorSet = STATE["ps"]
    with threadpool_limits(1), np.errstate(all="ignore"):
        t0 = time.perf_counter()
        mat = Material.from_dict({"name": name, "lobes": [{"type": "nbrdf", "path": str(Path(folder) / name)}]})
        cached = Path(job["cache"]) / f"{name}.npy"
        if cached.is_file():
            truth = np.load(cached).astype(np.float64)
        else:
            truth = merltable.tabulate(mat.eval)
            cached.parent.mkdir(parents=True, exist_ok=True)
            np.save(cached, truth.astype(np.float32))
        truth = BR._as_read(truth)
        tb = cmp.Brdf(name, "merl", merltable.brdf_of(truth), truth)
        small, full = cmp.reference(tb, 64, n_pairs=1000), cmp.reference(tb, 128, n_pairs=1000)
        rec: dict[str, Any] = {"material": name, "database": BR.database_of(folder, name)}
        m = ps.names.index(name)
        own = STATE["sp"].factors[m]
        rec["floor structured-all"] = _psnr(S.tabulate(own, STATE["sp"].scales[m], ["R", "G", "B"], {}), full)
        for mode in job["modes"]:
            incs = BR.incidences_of(mode)
            s = BR.slices_of(mat, incs)
            if not job["dev"]:
                for c, v in floors(name, incs, small, full).items():
                    rec[f"floor {c} {mode}"] = v
            recs = DEV_RECS(s, ps, name) if job["dev"] else DEFAULT_RECS(s, ps, name)
            for c, fn in recs.items():
                t1 = time.perf_counter()
                r = fn()  # noqa: B023 (called at once)
                rec[f"seconds {c} {mode}"] = time.perf_counter() - t1
                rec[f"rec {c} {mode}"] = _psnr(r, full)
        rec["seconds"] = time.perf_counter() - t0
    return rec


def write_sheet(path: Path, names: list[str], folders: list[Path], mode: str = "1") -> None:
    """Spheres (key light; the truth's exposure) of the truth and of every candidate's reconstruction from the
    slices of ``mode``, a row per material, each labelled with its PSNR (128-pixel renders, both lightings)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from reconstruction.core import merltable
    from reconstruction.core.models import Material
    from reconstruction.report import compare as cmp

    ps: P.PriorSet = STATE["ps"]
    where = {n: f for f in folders for n in BR.material_names(f)}
    fig, axes = plt.subplots(len(names), 1 + len(CANDIDATES), figsize=(1.6 * (1 + len(CANDIDATES)), 1.75 * len(names)),
                             squeeze=False)
    for row, name in zip(axes, names, strict=True):
        mat = Material.from_dict({"name": name, "lobes": [{"type": "nbrdf", "path": str(where[name] / name)}]})
        truth = BR._as_read(merltable.tabulate(mat.eval))
        ref = cmp.reference(cmp.Brdf(name, "merl", merltable.brdf_of(truth), truth), 128, n_pairs=1000)
        s = BR.slices_of(mat, BR.incidences_of(mode))
        shown = {"truth": (BR._display(ref.images, ref.images)["key"], name[:26])}
        for c, fn in DEFAULT_RECS(s, ps, name).items():
            t = BR._as_read(fn().table())
            imgs = cmp.render_images(cmp.Brdf(c, "merl", merltable.brdf_of(t), t), 128)
            psnr = cmp.image_metrics(imgs, ref.images, 128)["psnr_db"]
            shown[c] = (BR._display(imgs, ref.images)["key"], f"{c}: {psnr:.1f} dB")
        for ax, (img, label) in zip(row, shown.values(), strict=True):
            ax.imshow(img, interpolation="nearest")
            ax.set_title(label, fontsize=6)
            ax.axis("off")
    fig.suptitle(f"truth and each candidate prior from {BR._label(mode)} (key light)", fontsize=8)
    fig.tight_layout(rect=(0.0, 0.0, 1.0, 1.0 - 0.35 / fig.get_figheight()))
    fig.savefig(path, dpi=90)
    plt.close(fig)


def auto_prior_from_docs(page: Path) -> dict[tuple[str, str], float]:
    """(material, case) -> auto+prior's PSNR (dB) from the per-material table of docs/real-materials.md."""
    out: dict[tuple[str, str], float] = {}
    head: list[str] = []
    for line in page.read_text(encoding="utf-8").splitlines():
        if line.startswith("| material |"):
            head = [c.strip() for c in line.strip("|").split("|")]
        elif head and line.startswith("| ") and not line.startswith("|---"):
            cells = [c.strip() for c in line.strip("|").split("|")]
            for j, h in enumerate(head):
                if h.startswith("auto+prior (") and j < len(cells):
                    try:
                        out[(cells[0], h[len("auto+prior ("):-1])] = float(cells[j].split("/")[0])
                    except ValueError:
                        pass
    return out


def summary(rows: list[dict[str, Any]], modes: list[str], docs: dict[tuple[str, str], float]) -> list[str]:
    """Markdown table lines: per case, kind (floor / reconstruction) and candidate, median / worst per database."""
    dbs = ("all", *BR.DATABASES)
    lines = ["| slices | candidate | " + " | ".join(f"{d} median / worst (dB)" for d in dbs) + " |",
             "|---|---|" + "---|" * len(dbs)]

    def cell(key_of: Any) -> str:
        parts = []
        for d in dbs:
            v = [key_of(r) for r in rows if d == "all" or r["database"] == d]
            v = np.array([x for x in v if x is not None], dtype=np.float64)
            parts.append(f"{np.median(v):.1f} / {v.min():.1f} [{v.size}]" if v.size else "-")
        return " | ".join(parts)

    lines.append("| - | floor structured-all (own factors, every cell) | " +
                 cell(lambda r: r["floor structured-all"]) + " |")
    for mode in modes:
        for kind, label in (("floor", "floor "), ("rec", "")):
            names = dict.fromkeys(k.split()[1] for r in rows for k in r if k.startswith(f"{kind} ")
                                  and k.endswith(f" {mode}"))
            for c in names:
                lines.append(f"| {mode} | {label}{c} | " + cell(lambda r, k=f"{kind} {c} {mode}": r.get(k)) + " |")
        lines.append(f"| {mode} | auto+prior (docs run) | " +
                     cell(lambda r, m=mode: docs.get((r["material"], m))) + " |")
    return lines


def compare_real(path: Path, docs: dict[tuple[str, str], float]) -> list[str]:
    """Lines: per method and case of a bench_real_materials.py run (``path``, its records), PSNR median / worst per
    database beside today's auto+prior of the docs run on the same materials, and the per-material differences."""
    recs = [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    recs = [r for r in recs if "psnr_db" in r and "method" in r]
    out = ["| slices | method | " + " | ".join(f"{d} median / worst (dB)" for d in ("all", *BR.DATABASES)) +
           " | median difference, better / worse by > 0.5 dB |", "|---|---|---|---|---|---|---|"]
    for mode in dict.fromkeys(r["slices"] for r in recs):
        for m in dict.fromkeys(r["method"] for r in recs):
            rs = [r for r in recs if r["slices"] == mode and r["method"] == m and (r["material"], mode) in docs]
            for label, val in ((m, lambda r: r["psnr_db"]),
                               ("auto+prior (docs run)", lambda r, md=mode: docs[(r["material"], md)])):
                cells = []
                for d in ("all", *BR.DATABASES):
                    v = np.array([val(r) for r in rs if d == "all" or r["database"] == d])
                    cells.append(f"{np.median(v):.1f} / {v.min():.1f} [{v.size}]" if v.size else "-")
                diff = np.array([r["psnr_db"] - docs[(r["material"], mode)] for r in rs])
                extra = (f"{np.median(diff):+.1f} dB, {int(np.sum(diff > 0.5))} / {int(np.sum(diff < -0.5))}"
                         if label == m and diff.size else "")
                out.append(f"| {mode} | {label} | " + " | ".join(cells) + f" | {extra} |")
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "realdata"))
    ap.add_argument("--every", type=int, default=6, help="every N-th material in name order (default 6: 24)")
    ap.add_argument("--offset", type=int, default=0, help="the first of them (default 0)")
    ap.add_argument("--materials", help="comma-separated names (instead of --every)")
    ap.add_argument("--slices", default="1,2,3")
    ap.add_argument("--workers", type=int, default=1)
    ap.add_argument("--truth-cache", default=str(ROOT / "out" / "real-materials-cache"))
    ap.add_argument("--jsonl", default=str(ROOT / "out" / "prior-candidates.jsonl"))
    ap.add_argument("--from-jsonl", help="summarise an earlier run's records")
    ap.add_argument("--real-jsonl", help="compare a bench_real_materials.py run's records (e.g. auto+prior-local) "
                                         "with the docs run's auto+prior on the same materials, and stop")
    ap.add_argument("--sheet", help="write spheres of the truth and every candidate (from --slices' first case) for "
                                    "--materials to this PNG, and stop")
    ap.add_argument("--dev", action="store_true",
                    help="no floors; the reconstructions for a grid of each candidate's defaults (DEV_*)")
    args = ap.parse_args(argv)
    modes = [m.strip() for m in args.slices.split(",") if m.strip()]
    docs = auto_prior_from_docs(ROOT / "docs" / "real-materials.md")
    if args.real_jsonl:
        print("\n".join(compare_real(Path(args.real_jsonl), docs)))
        return 0
    if args.from_jsonl:
        rows = [json.loads(line) for line in Path(args.from_jsonl).read_text().splitlines() if line.strip()]
        print("\n".join(summary(rows, modes, docs)))
        return 0
    folders = [Path(args.data) / f for f in BR.FOLDERS]
    if not all(f.is_dir() for f in folders):
        print(f"bench_prior_candidates: {folders} not found (see ../shared/realdata/README.md)", file=sys.stderr)
        return 2
    from reconstruction.core import render

    render._OPERATOR_CACHE_SIZE = 16  # two render sizes x two lightings x two parts: keep all 8 operators
    t0 = time.perf_counter()
    STATE["ps"] = ps = P.load_prior([str(f) for f in folders])
    ps._fc()
    fcache = Path(args.truth_cache).parent / "structured-factors.npz"
    if fcache.is_file() and list(np.load(fcache)["names"]) == ps.names:
        z = np.load(fcache)
        STATE["sp"] = S.StructuredPrior(list(ps.names), z["factors"], z["scales"])
    else:
        STATE["sp"] = S.structured_prior(ps)
        fcache.parent.mkdir(parents=True, exist_ok=True)
        np.savez(fcache, names=np.array(ps.names), factors=STATE["sp"].factors, scales=STATE["sp"].scales)
    print(f"prior of {len(ps.names)} materials and their factors: {time.perf_counter() - t0:.0f} s", flush=True)
    if args.sheet:
        from threadpoolctl import threadpool_limits

        with threadpool_limits(1), np.errstate(all="ignore"), warnings.catch_warnings():
            warnings.simplefilter("ignore")
            write_sheet(Path(args.sheet), [n.strip() for n in (args.materials or "").split(",") if n.strip()],
                        folders, modes[0])
        return 0
    where = {n: str(f) for f in folders for n in BR.material_names(f)}
    want = ([n.strip() for n in args.materials.split(",")] if args.materials
            else sorted(ps.names)[args.offset::max(1, args.every)])
    jobs = [{"name": n, "folder": where[n], "modes": modes, "cache": args.truth_cache, "dev": args.dev}
            for n in want]
    rows = []
    out = Path(args.jsonl)
    out.parent.mkdir(parents=True, exist_ok=True)
    import multiprocessing

    pool = multiprocessing.get_context("fork").Pool(args.workers) if args.workers > 1 else None
    try:
        with out.open("w") as fh:
            for r in pool.imap_unordered(run_material, jobs) if pool is not None else map(run_material, jobs):
                rows.append(r)
                fh.write(json.dumps(r) + "\n")
                fh.flush()
                figs = " ".join(f"{k}={v:.1f}" for k, v in r.items() if k.startswith(("floor", "rec")))
                print(f"{r['material']:34s} {figs} ({r['seconds']:.0f} s)", flush=True)
    finally:
        if pool is not None:
            pool.close()
    print("\n".join(summary(rows, modes, docs)))
    print(f"{time.perf_counter() - t0:.0f} s, {len(rows)} material(s)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
