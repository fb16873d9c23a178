"""How close the best principled material (OpenPBR Surface, reconstruction.principled) comes to real materials, and
what the fit and the three exports cost.

For every material of ``../shared/realdata`` (``nbrdf-merl``: 48 MERL materials, the quick development set;
``nbrdf-extra``: 40 more MERL, 47 RGL and 6 Nielsen materials; 141 in all; neural BRDFs evaluated directly, see
that folder's README; never copied into the project), fits the principled material to the true material (the
NBRDF) and writes the MaterialX, glTF and Blender files, then reports:

* ``image``: relative RMSE of the linear renders of the principled material against the truth's, mean over the
  default views 'key' and 'rim' (reconstruction.core.metrics.image_errors, pixels seen within 80 deg);
* ``cosl2``: relative cosine-weighted L2 over direction pairs drawn uniformly with both angles <= 80 deg;
* what the principled material misses most (the report's sentence);
* the time per material of the fit (judging included) and the three exports: wall and CPU seconds.

With ``--from-slices``, also fits the principled material to a reconstruction (``--method fit`` from two
in-plane slices at 40 and 70 deg, as a bench measures them) and judges that against the truth.

Prints a line per material, then per database (MERL / RGL / Nielsen) the median and the worst image error and
the time; ``--markdown`` prints the summary table as docs/formats.md shows it. Usage::

    .venv/bin/python benchmarks/bench_principled.py [--quick] [--data ../shared/realdata] [--workers 2]
        [--materials NAME,NAME] [--from-slices] [--markdown]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
import warnings
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path
from typing import Any

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.core.models import NBRDF_SUFFIXES, Material  # noqa: E402
from reconstruction.principled.blender import write_blender  # noqa: E402
from reconstruction.principled.fit import IMAGE_SIZE, cosl2, fit_principled  # noqa: E402
from reconstruction.principled.gltf import write_gltf  # noqa: E402
from reconstruction.principled.materialx import write_materialx  # noqa: E402

DATABASES = ("MERL", "RGL", "Nielsen")


def materials(data: Path, quick: bool) -> list[tuple[str, str, Path]]:
    """(database, name, NBRDF prefix) of every material with its six npy files."""
    out = []
    for sub in ("nbrdf-merl",) if quick else ("nbrdf-merl", "nbrdf-extra"):
        folder = data / sub
        for p in sorted(folder.glob(f"*_{NBRDF_SUFFIXES[0]}.npy")):
            name = p.name[: -len(f"_{NBRDF_SUFFIXES[0]}.npy")]
            if not all((folder / f"{name}_{s}.npy").is_file() for s in NBRDF_SUFFIXES):
                continue
            db = ("RGL" if name.startswith("rgl-") else "Nielsen" if name.startswith("nielsen-") else "MERL")
            out.append((db, name, folder / name))
    return out


def _from_slices(mat: Material, truth: Any) -> dict[str, float]:
    """The principled material fitted to a ``fit`` reconstruction of two slices (40, 70 deg), judged against the
    truth."""
    from reconstruction import pipeline
    from reconstruction.core.metrics import image_errors
    from reconstruction.synthetic import synthetic_slice

    s = synthetic_slice(mat, (40.0, 70.0))
    rec, _ = pipeline.reconstruct(s, "fit")
    fit = fit_principled(rec.eval, judge=False)
    img = image_errors(fit.params.eval, truth, size=IMAGE_SIZE)
    return {"slices_image": float(np.mean([v["relative_rmse"] for v in img.values()])),
            "slices_cosl2": cosl2(fit.params.eval, truth)}


def run_one(item: tuple[str, str, Path], from_slices: bool = False) -> dict[str, Any]:
    db, name, prefix = item
    warnings.simplefilter("ignore")
    mat = Material.from_dict({"name": name, "lobes": [{"type": "nbrdf", "path": str(prefix)}]})
    truth = mat.eval
    truth(np.array([[0.0, 0.0, 1.0]]), np.array([[0.0, 0.0, 1.0]]))  # load the weights before timing
    w0, c0 = time.perf_counter(), time.process_time()
    fit = fit_principled(truth)
    w1, c1 = time.perf_counter(), time.process_time()
    with tempfile.TemporaryDirectory() as tmp:
        write_materialx(Path(tmp) / "m.mtlx", fit.params, name, fit.sentence)
        write_gltf(Path(tmp) / "m.gltf", fit.params, name, {"summary": fit.sentence})
        write_blender(Path(tmp) / "m.py", fit.params, name, fit.sentence)
    w2, c2 = time.perf_counter(), time.process_time()
    row = {"database": db, "name": name, "image": fit.image_relative_rmse, "cosl2": fit.cosl2,
           "misses": fit.misses, "share": fit.miss_share, "fit_wall_s": fit.seconds, "judge_wall_s": fit.judge_seconds,
           "fit_cpu_s": c1 - c0,
           "export_wall_s": w2 - w1, "wall_s": w2 - w0, "cpu_s": c2 - c0,
           "metal": fit.params.base_metalness, "roughness": fit.params.specular_roughness,
           "coat": fit.params.coat_weight, "fuzz": fit.params.fuzz_weight}
    if from_slices:
        row.update(_from_slices(mat, truth))
    return row


def summarise(rows: list[dict[str, Any]], markdown: bool) -> None:
    print()
    head = ("| database | materials | image error: median | worst (material) | cosl2 median | "
            "time per material: median / max wall (CPU) |")
    lines = [head, "|---|---|---|---|---|---|"]
    for db in (*DATABASES, "all"):
        rs = [r for r in rows if db in ("all", r["database"])]
        if not rs:
            continue
        img = np.array([r["image"] for r in rs])
        worst = rs[int(np.argmax(img))]
        wall = np.array([r["wall_s"] for r in rs])
        cpu = np.array([r["cpu_s"] for r in rs])
        lines.append(f"| {db} | {len(rs)} | {np.median(img):.1%} | {img.max():.1%} ({worst['name']}) | "
                     f"{np.median([r['cosl2'] for r in rs]):.1%} | {np.median(wall):.2f} s / {wall.max():.2f} s "
                     f"({np.median(cpu):.2f} s / {cpu.max():.2f} s CPU) |")
    print("\n".join(lines) if markdown else "\n".join(lines).replace("|", " ").replace("  ", " "))
    if any("slices_image" in r for r in rows):
        s = np.array([r["slices_image"] for r in rows])
        print(f"\nfitted to a fit reconstruction of 2 slices (40, 70 deg), judged against the truth: image error "
              f"median {np.median(s):.1%}, worst {s.max():.1%}")
    misses: dict[str, int] = {}
    for r in rows:
        misses[r["misses"]] = misses.get(r["misses"], 0) + 1
    print("\nwhat the principled material misses most: " + "; ".join(f"{k} ({v})" for k, v in
                                                                   sorted(misses.items(), key=lambda kv: -kv[1])))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--data", default=str(ROOT.parent / "shared" / "realdata"),
                    help="the real-data folder (with nbrdf-merl/ and nbrdf-extra/); default ../shared/realdata")
    ap.add_argument("--quick", action="store_true", help="the 48 materials of nbrdf-merl only")
    ap.add_argument("--materials", help="comma-separated material names (default: all)")
    ap.add_argument("--workers", type=int, default=1, help="processes (default 1: the timings of one core)")
    ap.add_argument("--from-slices", action="store_true",
                    help="also fit to a reconstruction from two slices and judge it against the truth")
    ap.add_argument("--markdown", action="store_true", help="print the summary as a markdown table")
    args = ap.parse_args(argv)
    items = materials(Path(args.data), args.quick)
    if args.materials:
        want = set(args.materials.split(","))
        items = [i for i in items if i[1] in want]
    if not items:
        print(f"no materials under {args.data}", file=sys.stderr)
        return 2
    rows = []
    print(f"{'database':8s} {'material':40s} {'image':>7s} {'cosl2':>7s} {'wall s':>7s} {'cpu s':>6s}  misses")
    with ProcessPoolExecutor(args.workers) as ex:
        for r in ex.map(run_one, items, [args.from_slices] * len(items)):
            rows.append(r)
            extra = f"  slices {r['slices_image']:.1%}" if "slices_image" in r else ""
            print(f"{r['database']:8s} {r['name']:40s} {r['image']:7.1%} {r['cosl2']:7.1%} {r['wall_s']:7.2f} "
                  f"{r['cpu_s']:6.2f}  {r['misses']} ({r['share']:.0%}){extra}", flush=True)
    summarise(rows, args.markdown)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
