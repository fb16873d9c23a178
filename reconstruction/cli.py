"""gonio-reconstruct: in-plane slices -> a full isotropic BRDF as a MERL table, a preview and a report.

Example::

    gonio-reconstruct out/demo/slice.csv --method auto --out out/demo/material.binary \\
        --preview out/demo/material.exr --report out/demo/material.json

Bad input exits with status 2 and one line on stderr naming the file, line and what was expected.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from .base import ReconstructionError
from .merl import FILE_SIZE, MerlError
from .models import MaterialError
from .slicefile import QUANTITIES, SliceError

PROG = "gonio-reconstruct"
DESCRIPTION = """\
Reconstruct a full isotropic BRDF from in-plane slices and write it as a MERL table (.binary, 34,992,012 bytes).

Inputs are gonio-brdf slice files (docs/slice-format.md) or generic CSV tables from other instruments' software
(an incidence column, a measured-angle column, one column per wavelength such as 450nm or per channel: value, or
R,G,B); generic tables need --quantity. Several inputs (e.g. one per incidence) are merged. All-zero rows in
the retro blind spot are missing data and are interpolated, not taken as zero.

Methods: fit (analytic lobes chosen by BIC, energy-constrained), microfacet (a tabulated normal distribution
with Smith shadowing and a physical Fresnel), bivariate (f tabulated over theta_h, theta_d), revolve (the
thesis's solids of revolution), auto (the method that best predicts held-out samples: leave-one-incidence-out,
or held-out blocks of theta_o with one slice; the report says which and why). Spectral data are converted to
linear sRGB (CIE 1931 2 degree observer, --illuminant); grey data give a grey table.

A table that fails a plausibility check (negative or missing cells, directional albedo above 1, a
non-reciprocal BRDF) is not written: the command exits with status 3 and says which check failed, unless
--allow-implausible is given."""

EXIT_IMPLAUSIBLE = 3


class ImplausibleError(ReconstructionError):
    """The reconstruction fails a plausibility check; nothing was written."""


def _supersample(text: str) -> tuple[int, int, int] | str:
    if text == "adaptive":
        return text
    parts = text.split(",")
    try:
        vals = [int(p) for p in parts]
    except ValueError:
        raise argparse.ArgumentTypeError(f"expected N or NH,ND,NP (positive integers), got {text!r}") from None
    if len(vals) == 1:
        vals = vals * 3
    if len(vals) != 3 or min(vals) < 1:
        raise argparse.ArgumentTypeError(f"expected N or NH,ND,NP (positive integers), got {text!r}")
    return (vals[0], vals[1], vals[2])


def _illuminant(text: str) -> str:
    if text == "D65":
        return text  # the default: no need to load colour-science to check it
    from .colour import illuminant_names

    names = illuminant_names()
    if text not in names:
        raise argparse.ArgumentTypeError(f"unknown illuminant {text!r}; e.g. {', '.join(n for n in names[:12])}, ...")
    return text


def _number(cast: Callable[[str], Any], ok: Callable[[Any], bool], what: str) -> Callable[[str], Any]:
    """An argparse ``type``: ``cast(text)`` that must satisfy ``ok``; errors say ``what`` was expected."""

    def parse(text: str) -> Any:
        try:
            v = cast(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}") from None
        if not ok(v):
            raise argparse.ArgumentTypeError(f"expected {what}, got {text!r}")
        return v

    return parse


_positive_int = _number(int, lambda v: v >= 1, "a positive integer")
_nonneg_float = _number(float, lambda v: v >= 0, "a number >= 0")


def build_parser() -> argparse.ArgumentParser:
    from .pipeline import METHODS

    ap = argparse.ArgumentParser(prog=PROG, description=DESCRIPTION,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="*", metavar="INPUT",
                    help="slice files or generic CSV tables, or one Zemax tabular BSDF file (.bsdf)")
    ap.add_argument("--method", choices=METHODS, default="auto", help="reconstruction method (default: auto)")
    ap.add_argument("--out", metavar="MATERIAL.binary", help="MERL table to write (required unless --batch)")
    ap.add_argument("--preview", metavar="MATERIAL.exr",
                    help="render a sphere under a point light: linear float OpenEXR, plus a PNG next to it")
    ap.add_argument("--report", metavar="MATERIAL.json",
                    help="JSON report: method and why, parameters, residuals, coverage, plausibility checks")
    ap.add_argument("--supersample", nargs="?", const="adaptive", type=_supersample, default=None,
                    metavar="adaptive|N|NH,ND,NP",
                    help="write cell averages instead of bin-centre values: 'adaptive' (the default when the flag "
                         "has no value: averages where f is far from linear across a cell, ~2 s) or NH x ND x NP "
                         "sub-samples in every cell (8,2,2 takes ~15 s)")
    ap.add_argument("--quantity", choices=QUANTITIES,
                    help="what the values of generic tables are: brdf (1/sr), reflectance_factor (pi f_r) or "
                         "brdf_cos (f_r cos theta_o); slice files say it themselves")
    ap.add_argument("--columns", metavar="KEY=NAME,...",
                    help="map generic-table columns: theta_i=NAME,theta_o=NAME (also value=NAME, R=, G=, B=)")
    ap.add_argument("--blind-spot-deg", type=_nonneg_float, default=None, metavar="DEG",
                    help="half width of the retro blind spot in |theta_i + theta_o| where all-zero rows are missing "
                         "data (default: the slice file's blind_spot_half_width_deg, else 10)")
    ap.add_argument("--illuminant", default="D65", type=_illuminant,
                    help="illuminant for spectral -> RGB (default D65; e.g. D50, A; any colour-science name)")
    ap.add_argument("--scene", metavar="SCENE.toml",
                    help="scene file (configs/scenes/*.toml): ranges, angular resolution and error budget that "
                         "restrict the fit's candidate models")
    ap.add_argument("--lobes", metavar="KIND,...",
                    help="lobe kinds the fit may use: lambert, ggx, beckmann, retro, fresnel (default: all)")
    ap.add_argument("--fill", choices=("interpolate", "zero"), default="interpolate",
                    help="holes (blind spot, missing samples): interpolate (default) or leave zero "
                         "(bivariate, revolve; a fitted model covers holes itself)")
    ap.add_argument("--axis", default="auto", choices=("auto", "vertical", "pca"),
                    help="revolve: axis of each sub-curve, vertical through its highest point or its first principal "
                         "component (auto: chosen per sub-curve)")
    ap.add_argument("--smoothing", type=_nonneg_float, default=None, help="revolve: smoothing (passed through)")
    ap.add_argument("--allow-implausible", action="store_true",
                    help="write the table even if it fails a plausibility check (the report and the console say so)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar and no summary line")
    from .exports import add_arguments as add_format_arguments

    add_format_arguments(ap)
    b = ap.add_argument_group("batch reconstruction of a folder of slices")
    b.add_argument("--batch", metavar="FOLDER",
                   help="reconstruct every FOLDER/*.csv and FOLDER/*/slice.csv (capture folders) separately, in "
                        "parallel, into --out-dir: NAME.binary, NAME.json and, with --previews, NAME.exr/.png")
    b.add_argument("--out-dir", metavar="DIR", help="batch output folder (default: the batch folder)")
    b.add_argument("--previews", action="store_true", help="batch: also render a preview per material")
    b.add_argument("--scheduler", metavar="ADDRESS",
                   help="batch: run on a dask.distributed cluster at ADDRESS (pip install 'gonio-brdf[dask]')")
    b.add_argument("--workers", type=_positive_int, default=None, metavar="N",
                   help="batch: local worker processes (default: CPU count)")
    ap.epilog = ("examples:\n"
                 "  gonio-reconstruct out/demo/slice.csv --out out/demo/material.binary "
                 "--preview out/demo/material.exr\n"
                 "  gonio-reconstruct other.csv --quantity reflectance_factor --columns theta_i=inc,theta_o=det "
                 "--method fit --out m.binary\n"
                 "  gonio-reconstruct --batch captures/ --out-dir materials/ --previews --workers 2")
    return ap


def _check_output(path: Path, suffix: str, flag: str) -> None:
    if path.suffix.lower() != suffix:
        raise ReconstructionError(f"{flag} {path}: expected a file name ending in {suffix}")
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ReconstructionError(f"{flag} {path}: the folder {parent} does not exist")


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Do the work of one command line; returns the report (also written with --report)."""
    from . import colour, exports, inputs, pipeline, preview, report, zemax
    from .scene import LOBE_KINDS, load_scene

    out = Path(args.out) if args.out else None
    if out is not None:
        _check_output(out, ".binary", "--out")
    exports.check_arguments(args)
    if args.preview:
        _check_output(Path(args.preview), ".exr", "--preview")
    if args.report:
        parent = Path(args.report).parent
        if str(parent) and not parent.is_dir():
            raise ReconstructionError(f"--report {args.report}: the folder {parent} does not exist")
    lobes = None
    if args.lobes:
        lobes = [x.strip() for x in args.lobes.split(",") if x.strip()]
        unknown = [x for x in lobes if x not in LOBE_KINDS]
        if unknown:
            raise ReconstructionError(f"--lobes: unknown kind(s) {unknown}; expected {', '.join(LOBE_KINDS)}")
    timings: dict[str, float] = {}
    steps = ["read", "colour", "reconstruct", "tabulate", "write", "checks"] + (["preview"] if args.preview else [])
    bar = tqdm(total=len(steps), desc=PROG, unit="step", disable=True if args.quiet else None, file=sys.stderr,
               leave=False)

    def step(name: str) -> float:
        bar.set_postfix_str(name)
        return time.perf_counter()

    def done(name: str, t0: float) -> None:
        timings[name] = time.perf_counter() - t0
        bar.update(1)

    try:
        t0 = step("reading inputs")
        loaded = zemax.load_inputs(args.inputs, args.quantity, args.columns) or inputs.load_inputs(
            args.inputs, quantity=args.quantity, columns=inputs.parse_columns(args.columns),
            blind_spot_deg=args.blind_spot_deg)
        scene = load_scene(args.scene) if args.scene else None
        done("read", t0)
        t0 = step("colour")
        working, colour_info = colour.to_working_channels(loaded.slice, args.illuminant)
        done("colour", t0)
        t0 = step("reconstructing")
        opts = pipeline.Options(scene=scene, fill=args.fill, lobes=lobes, revolve_axis=args.axis,
                                revolve_smoothing=args.smoothing)
        rec, choice = pipeline.reconstruct(working, args.method, opts,
                                           progress=lambda name: bar.set_postfix_str(f"fitting {name}"))
        done("reconstruct", t0)
        t0 = step("tabulating" + (f" (supersample {args.supersample})" if args.supersample else ""))
        table = pipeline.tabulate(rec, args.supersample)
        done("tabulate", t0)
        t0 = step("plausibility checks")
        checks = report.plausibility(rec, table)
        done("checks", t0)
        if not checks["all_pass"] and not getattr(args, "allow_implausible", False):
            raise ImplausibleError(implausible_message(rec.method, checks))
        t0 = step("writing table")
        from . import merl

        outputs: dict[str, Any] = {}
        if out is not None:
            merl.write(out, table, require_above_horizon=True)
            outputs.update({"table": str(out), "table_bytes": out.stat().st_size})
        outputs.update(exports.write_outputs(args, rec, timings))
        done("write", t0)
        if args.preview:
            t0 = step("preview")
            outputs["preview"] = (exports.mitsuba_preview(args, rec, outputs) if args.preview_renderer == "mitsuba"
                                  else preview.write_preview(args.preview, table))
            done("preview", t0)
    finally:
        bar.close()
    rep = report.build_report(
        rec=rec, choice=choice, working=working, table=table, checks=checks,
        inputs={"files": loaded.files, "quantities": loaded.quantities, "notes": loaded.notes,
                "columns": args.columns, "scene": args.scene},
        colour=colour_info,
        table_info={"cells": 3 * merl.N_CELLS, "values": "cell averages" if args.supersample else "bin centres",
                    "supersample": (list(args.supersample) if isinstance(args.supersample, tuple)
                                    else args.supersample),
                    "bin_centres": "theta_h = ((i + 0.5) / 90)^2 * 90 deg, theta_d = j + 0.5 deg, "
                                   "phi_d = k + 0.5 deg"},
        outputs=outputs, timings=timings, dropped_blind_spot=loaded.dropped_blind_spot)
    if not checks["all_pass"]:
        rep["implausible_table_written"] = "written with --allow-implausible: " + implausible_message(rec.method,
                                                                                                      checks)
    if args.report:
        outputs["report"] = str(args.report)
        rep["outputs"]["report"] = str(args.report)
        report.write_json(args.report, rep)
    return rep


def implausible_message(method: str, checks: dict[str, Any]) -> str:
    """One line: which plausibility checks of ``checks`` failed, with figures, and what to try."""
    why = []
    if not checks["non_negative"]["pass"]:
        c = checks["non_negative"]
        why.append(f"non_negative: {c['missing_cells']} cell(s) without a value, minimum {c['min_1_per_sr']:.3g} 1/sr")
    if not checks["albedo"]["pass"]:
        c = checks["albedo"]
        alb = np.asarray(c["albedo"], dtype=np.float64)
        k = int(np.argmax(alb.max(axis=1)))
        why.append(f"albedo: the table reflects more light than it receives (directional albedo {alb.max():.3g} > "
                   f"1 + {c['tolerance']:g} at theta_i = {c['theta_i_deg'][k]:g} deg)")
    if not checks["reciprocity"]["pass"]:
        why.append(f"reciprocity: relative error {checks['reciprocity']['relative_error']:.3g}")
    return (f"method {method}: the table fails the plausibility check(s) " + "; ".join(why)
            + "; nothing written. Try --method fit or microfacet (energy-conserving by construction), slices at "
              "more incidences, or --allow-implausible to write it anyway")


def batch_files(folder: Path) -> list[tuple[str, Path]]:
    """(name, path) of every slice to reconstruct in ``folder``: ``*.csv`` (name = stem) and ``*/slice.csv``
    (name = the capture folder's name), sorted by name."""
    found = [(p.stem, p) for p in folder.glob("*.csv")] + [(p.parent.name, p) for p in folder.glob("*/slice.csv")]
    return sorted(found)


def _batch_one(job: tuple[dict[str, Any], str, Path, Path]) -> dict[str, Any]:
    """Worker: reconstruct one file of a batch with the shared options; never raises (the result says)."""
    options, name, path, out_dir = job
    ns = argparse.Namespace(**options)
    ns.inputs = [str(path)]
    ns.out = str(out_dir / f"{name}.binary")
    ns.report = str(out_dir / f"{name}.json")
    ns.preview = str(out_dir / f"{name}.exr") if options.get("previews") else None
    ns.quiet = True
    try:
        rep = run(ns)
    except ImplausibleError as e:
        return {"name": name, "input": str(path), "ok": False, "error": str(e), "implausible": True}
    except (ReconstructionError, SliceError, MerlError, MaterialError, OSError) as e:
        return {"name": name, "input": str(path), "ok": False, "error": str(e)}
    return {"name": name, "input": str(path), "ok": True, "method": rep["method"], "table": ns.out}


def run_batch(args: argparse.Namespace) -> int:
    """Reconstruct every slice of ``args.batch`` through the executor; print one line per file."""
    from .executor import make_executor, run_all

    folder = Path(args.batch)
    if not folder.is_dir():
        print(f"{PROG}: error: --batch {folder}: not a folder", file=sys.stderr)
        return 2
    files = batch_files(folder)
    if not files:
        print(f"{PROG}: error: --batch {folder}: no *.csv or */slice.csv inside", file=sys.stderr)
        return 2
    out_dir = Path(args.out_dir) if args.out_dir else folder
    out_dir.mkdir(parents=True, exist_ok=True)
    options = {k: v for k, v in vars(args).items() if k not in ("inputs", "out", "preview", "report", "batch")}
    results: list[dict[str, Any]] = []
    with tqdm(total=len(files), desc=PROG, unit="file", disable=True if args.quiet else None,
              file=sys.stderr) as bar:
        def done(_job: Any, fut: Any) -> None:
            results.append(fut.result())
            bar.update(1)

        try:
            with make_executor(args.scheduler, args.workers) as ex:
                run_all(ex, _batch_one, [(options, n, p, out_dir) for n, p in files], on_done=done)
        except RuntimeError as e:
            print(f"{PROG}: error: {e}", file=sys.stderr)
            return 2
    failed = 0
    for r in sorted(results, key=lambda r: r["name"]):
        if r["ok"]:
            print(f"{r['name']}: {r['method']} -> {r['table']}", file=sys.stderr)
        else:
            failed += 1
            print(f"{r['name']}: error: {r['error']}", file=sys.stderr)
    print(f"{PROG}: {len(files) - failed} of {len(files)} reconstructed into {out_dir}", file=sys.stderr)
    return 1 if failed else 0


def main(argv: list[str] | None = None) -> int:
    ap = build_parser()
    args = ap.parse_args(argv)
    if args.batch:
        from .exports import wants_outputs

        if args.inputs or args.out or args.preview or args.report or wants_outputs(args):
            ap.error("--batch takes no INPUT, --out, --preview, --report, --rgl, --zemax, --export-mitsuba or "
                     "--export-json (outputs are named after the inputs)")
        return run_batch(args)
    from .exports import wants_outputs

    if not args.inputs or not (args.out or wants_outputs(args)):
        ap.error("give INPUT... and --out MATERIAL.binary (or --rgl, --zemax, --export-mitsuba, --export-json; or "
                 "--batch FOLDER)")
    try:
        rep = run(args)
    except ImplausibleError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return EXIT_IMPLAUSIBLE
    except (ReconstructionError, SliceError, MerlError, MaterialError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        where = f"{e.filename}: " if e.filename else ""
        print(f"{PROG}: error: {where}{e.strerror or e}", file=sys.stderr)
        return 2
    if not args.quiet:
        checks = rep["checks"]
        failed = [k for k in ("non_negative", "albedo", "reciprocity") if not checks[k]["pass"]]
        model = f" ({rep['details']['model']})" if "model" in rep.get("details", {}) else ""
        written = [f"{rep['outputs']['table']} ({FILE_SIZE:,} bytes)"] if "table" in rep["outputs"] else []
        written += [rep["outputs"][k][f] for k, f in (("rgl", "rgl"), ("zemax", "zemax"), ("mitsuba", "xml"))
                    if k in rep["outputs"]]
        written += [rep["outputs"]["parameters_json"]] if "parameters_json" in rep["outputs"] else []
        print(f"{PROG}: method {rep['method']}{model}: wrote {', '.join(written)}"
              + (f"; IMPLAUSIBLE, written because of --allow-implausible: check(s) failed: {', '.join(failed)}"
                 if failed else "; checks passed"), file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
