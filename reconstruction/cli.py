"""gonio-reconstruct: in-plane slices -> a full isotropic BRDF as a MERL table, a preview and a report.

Example::

    gonio-reconstruct out/demo/slice.csv --method auto --out out/demo/material.binary \\
        --preview out/demo/material.exr --report out/demo/material.json

Bad input exits with status 2 and one line on stderr naming the file, line and what was expected; an I/O fault
while writing (a full disk) exits with status 1 and one line naming the file. Outputs are written atomically: a
failure never leaves a half-written file under its real name.
"""

from __future__ import annotations

import argparse
import errno
import os
import sys
import textwrap
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from reconstruction.atomic import is_no_space
from reconstruction.base import ReconstructionError
from reconstruction.core.merltable import MerlError
from reconstruction.core.models import MaterialError
from reconstruction.core.slicedata import SliceError, shorten
from reconstruction.formats.merl import FILE_SIZE
from reconstruction.job import ImplausibleError, Job
from reconstruction.pipeline import run as pipeline_run
from reconstruction.schema.slice_meta import QUANTITIES

__all__ = ["main", "build_parser", "run", "run_batch", "batch_files", "job_from_args", "EXIT_IMPLAUSIBLE"]

PROG = "gonio-reconstruct"
DESCRIPTION = """\
Reconstruct a full isotropic BRDF from in-plane slices and write it as a MERL table (.binary, 34,992,012 bytes).

Inputs are gonio-brdf slice files (docs/formats.md) or generic CSV tables from other instruments' software
(an incidence column, a measured-angle column, one column per wavelength such as 450nm or per channel: value, or
R,G,B); generic tables need --quantity. Several inputs (e.g. one per incidence) are merged. All-zero rows in
the retro blind spot are missing data and are interpolated, not taken as zero.

Methods (each declared by its module in reconstruction/methods/plugins/):
{methods}
Spectral data are converted to linear sRGB (CIE 1931 2 degree observer, --illuminant); grey data give a grey table.

A table that fails a plausibility check (negative or missing cells, directional albedo above 1, a
non-reciprocal BRDF) is not written: the command exits with status 3 and says which check failed, unless
--allow-implausible is given."""

EXIT_IMPLAUSIBLE = 3


def _description() -> str:
    """The command's description, its list of methods from the registry (a new method's summary appears here)."""
    from reconstruction.methods import REGISTRY

    auto = ("the method that best predicts held-out samples (leave-one-incidence-out, or held-out blocks of "
            "theta_o with one slice; the report says which and why)")
    width = max(len(n) for n in REGISTRY) + 1
    lines = [f"  {n + ':':<{width}} {m.summary}" for n, m in REGISTRY.items()]
    lines += textwrap.wrap(auto, 116, initial_indent=f"  {'auto:':<{width}} ", subsequent_indent=" " * (width + 3))
    return DESCRIPTION.format(methods="\n".join(lines))


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
    from reconstruction.core.colour import illuminant_names

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
    from reconstruction.cliutil import OneLineParser
    from reconstruction.methods import REGISTRY

    ap = OneLineParser(prog=PROG, description=_description(), formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("inputs", nargs="*", metavar="INPUT",
                    help="slice files or generic CSV tables, or one Zemax tabular BSDF file (.bsdf)")
    ap.add_argument("--method", choices=("auto", *REGISTRY), default="auto",
                    help="reconstruction method (default: auto, the one that best predicts held-out samples): "
                         + "; ".join(f"{m.name}: {m.summary}" for m in REGISTRY.values()))
    ap.add_argument("--out", metavar="MATERIAL.binary",
                    help="MERL table to write; optional once another output is asked (--preview, --html, --report, "
                         "--rgl, --zemax, --export-mitsuba, --export-json, --uncertainty, --principled, "
                         "--materialx, --gltf, --blender); not with --batch (--out-dir)")
    ap.add_argument("--preview", metavar="MATERIAL.exr",
                    help="render a sphere under a point light: linear float OpenEXR, plus a PNG next to it")
    ap.add_argument("--html", metavar="REPORT.html", nargs="?", const=True, default=None,
                    help="a self-contained HTML report: the slices with every method's prediction, the thesis's "
                         "polar curve, a (theta_h, theta_d) map, spheres, cuts, albedo, checks, parameters, the "
                         "choice (with --batch: no value, one page per material plus index.html)")
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
    ap.add_argument("--angles-in", choices=("degrees", "radians"), default="degrees",
                    help="unit of the angle columns of slice files and generic tables (default degrees; a file whose "
                         "angles all lie within +-1.6 is refused as radians read as degrees)")
    ap.add_argument("--blind-spot-deg", type=_nonneg_float, default=None, metavar="DEG",
                    help="half width of the retro blind spot in |theta_i + theta_o| where all-zero rows are missing "
                         "data (default: the slice file's blind_spot_half_width_deg, else 10)")
    ap.add_argument("--illuminant", default="D65", type=_illuminant,
                    help="illuminant for spectral -> RGB (default D65; e.g. D50, A; any colour-science name)")
    ap.add_argument("--scene", metavar="SCENE.toml",
                    help="scene file (configs/scenes/*.toml): ranges, angular resolution and error budget that "
                         "restrict the fit's candidate models")
    from reconstruction.methods.flags import add_arguments as add_method_arguments

    add_method_arguments(ap)  # every method's options that declare a flag (--lobes, --fill, --axis, --prior, ...)
    u = ap.add_argument_group("how sure the table is, and which slice to measure next")
    u.add_argument("--uncertainty", metavar="SIGMA.npy", default=None,
                   help="write the standard deviation of ln f_r per cell, float32 (C, 90, 90, 180) in the MERL "
                        "table's cell order; the report gets an 'uncertainty' section (median sigma over measured, "
                        "interpolated and extrapolated cells; expected PSNR, linear image error and cosl2)")
    u.add_argument("--advise", action="store_true",
                   help="rank the incidences the bench can still measure (every 5 deg) by the errors to expect "
                        "after measuring each, with its bench time, and recommend one (the report's 'advice')")
    u.add_argument("--bench", metavar="CONFIG.toml", default=None,
                   help="--advise: the bench file whose arm limits, blind spot and timing the candidates use "
                        "(default: the bench recorded in the slice file's metadata, else 0-80 deg, a 4 deg blind "
                        "spot, 0.13 s per point); never beyond the incidence where its beam overfills the sample")
    u.add_argument("--budget-s", type=_nonneg_float, default=None, metavar="T",
                   help="--advise: also plan the best further slices that fit in T seconds of bench time")
    ap.add_argument("--no-conservative", dest="conservative", action="store_false",
                    help="auto: write the chosen method's table as it extrapolates, also where no sample rests on a "
                         "cell (by default auto keeps those cells below the reference posterior's median x "
                         "exp(sigma), the --prior's; without a prior, the built-in analytic family's median x "
                         "exp(3 sigma) where that takes at least 10 %% of the light and holds the samples: the "
                         "report's 'conservative' section)")
    ap.add_argument("--allow-implausible", action="store_true",
                    help="write the table even if it fails a plausibility check (the report and the console say so)")
    ap.add_argument("--quiet", action="store_true", help="no progress bar and no summary line")
    from reconstruction.formats.exports import add_arguments as add_format_arguments

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


def job_from_args(args: argparse.Namespace, **overrides: Any) -> Job:
    """The :class:`~reconstruction.job.Job` of a parsed command line (``overrides``: fields to replace). A
    method's flag goes to the Job's field of its name (``fill``, ``axis``, ``prior_anchor``, ...) or, for a method
    without one, to :attr:`Job.options`."""
    from reconstruction.methods.flags import values as method_values

    fields: dict[str, Any] = dict(
        inputs=tuple(str(x) for x in (args.inputs or ())), out=str(args.out) if args.out else "",
        method=args.method, preview=args.preview, report=args.report, supersample=args.supersample,
        quantity=args.quantity, columns=args.columns, blind_spot_deg=args.blind_spot_deg, illuminant=args.illuminant,
        angles_in=getattr(args, "angles_in", None) or "degrees", scene=args.scene,
        allow_implausible=bool(getattr(args, "allow_implausible", False)),
        conservative=bool(getattr(args, "conservative", True)),
        html=args.html if isinstance(getattr(args, "html", None), str) else None,
        **{k: getattr(args, k, None) for k in ("rgl", "zemax", "zemax_incidences", "zemax_azimuths", "zemax_radials",
                                              "export_mitsuba", "export_json", "principled", "materialx", "gltf",
                                              "blender")},
        preview_renderer=getattr(args, "preview_renderer", None) or "builtin",
        uncertainty=getattr(args, "uncertainty", None), advise=bool(getattr(args, "advise", False)),
        bench=getattr(args, "bench", None), budget_s=getattr(args, "budget_s", None))
    own = set(Job.__dataclass_fields__)
    options: dict[str, Any] = {}
    for spec, value in method_values(args):
        if spec.dest in own:
            fields[spec.dest] = value or None if spec.kind == "list" else value
        else:
            options[spec.attr] = value
    fields["options"] = options
    fields.update(overrides)
    return Job(**fields)


class _Bar:
    """The progress bar of one command line: a step of :attr:`Job.steps` per tick, the current step beside it
    (shown from the first step on, after the outputs were checked)."""

    def __init__(self, job: Job, quiet: bool) -> None:
        self.total, self.quiet = len(job.steps), quiet
        self.bar: Any = None

    def begin(self, label: str) -> None:
        if self.bar is None:
            self.bar = tqdm(total=self.total, desc=PROG, unit="step", disable=True if self.quiet else None,
                            file=sys.stderr, leave=False)
        self.bar.set_postfix_str(label)

    def done(self, step: str) -> None:
        if self.bar is not None:
            self.bar.update(1)

    def build(self, what: str, done: int, total: int) -> None:
        """A long build under way (the prior's tabulation): its count beside the current step."""
        self.begin(f"{what}: {done}/{total}")

    def built(self, what: str, path: Path, size: int, seconds: float) -> None:
        """A build was cached: where, how large, how to clear it (printed even with --quiet: it is disk space)."""
        from reconstruction.cache import cache_dir

        tqdm.write(f"{PROG}: {what}: built in {seconds:.0f} s and cached in {path} ({size / 1e6:.0f} MB), read from "
                   f"there from now on; delete it to rebuild, or {cache_dir()} to clear every cache",
                   file=sys.stderr)

    def close(self) -> None:
        if self.bar is not None:
            self.bar.close()


def run(args: argparse.Namespace) -> dict[str, Any]:
    """Do the work of one command line (:func:`reconstruction.pipeline.run`); returns the report (also written
    with --report)."""
    from reconstruction.cache import BUILD_PROGRESS, BUILT

    job = job_from_args(args)
    bar = _Bar(job, args.quiet)
    hooks = BUILD_PROGRESS.set(bar.build), BUILT.set(bar.built)
    try:
        return pipeline_run(job, progress=bar)
    finally:
        BUILD_PROGRESS.reset(hooks[0])
        BUILT.reset(hooks[1])
        bar.close()


def batch_files(folder: Path) -> list[tuple[str, Path]]:
    """(name, path) of every slice to reconstruct in ``folder``: ``*.csv`` (name = stem) and ``*/slice.csv``
    (name = the capture folder's name), sorted by name."""
    found = [(p.stem, p) for p in folder.glob("*.csv")] + [(p.parent.name, p) for p in folder.glob("*/slice.csv")]
    return sorted(found)


def _batch_one(job: tuple[Job, str, Path]) -> dict[str, Any]:
    """Worker: reconstruct one file of a batch (its :class:`Job`); never raises (the result says)."""
    one, name, path = job
    from reconstruction.cliutil import plain_warnings

    try:
        with plain_warnings(PROG), np_quiet():
            rep = pipeline_run(one)
    except ImplausibleError as e:
        return {"name": name, "input": str(path), "ok": False, "error": str(e), "implausible": True}
    except (ReconstructionError, SliceError, MerlError, MaterialError) as e:
        return {"name": name, "input": str(path), "ok": False, "error": str(e)}
    except OSError as e:
        return {"name": name, "input": str(path), "ok": False, "error": _os_error(e)}
    except MemoryError as e:
        return {"name": name, "input": str(path), "ok": False, "error": out_of_memory(e)}
    except Exception as e:  # noqa: BLE001 - one file must never abort the batch
        return {"name": name, "input": str(path), "ok": False, "error": f"unexpected error: {type(e).__name__}: "
                                                                        f"{str(e)[:300]}"}
    return {"name": name, "input": str(path), "ok": True, "method": rep["method"], "table": one.out, "html": one.html}


def run_batch(args: argparse.Namespace) -> int:
    """Reconstruct every slice of ``args.batch`` through the executor; print one line per file."""
    from reconstruction.executor import make_executor, run_all

    folder = Path(args.batch)
    if not folder.is_dir():
        print(f"{PROG}: error: --batch {folder}: not a folder", file=sys.stderr)
        return 2
    files = batch_files(folder)
    if not files:
        print(f"{PROG}: error: --batch {folder}: no *.csv or */slice.csv inside", file=sys.stderr)
        return 2
    out_dir = Path(args.out_dir) if args.out_dir else folder
    try:
        out_dir.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        print(f"{PROG}: error: --out-dir {out_dir}: cannot create the folder ({e.strerror or e})", file=sys.stderr)
        return 2
    if not os.access(out_dir, os.W_OK | os.X_OK):
        print(f"{PROG}: error: --out-dir {out_dir}: the folder is not writable", file=sys.stderr)
        return 2
    jobs = [(job_from_args(args, inputs=(str(p),), out=str(out_dir / f"{n}.binary"),
                           report=str(out_dir / f"{n}.json"),
                           preview=str(out_dir / f"{n}.exr") if args.previews else None,
                           html=str(out_dir / f"{n}.html") if args.html else None), n, p) for n, p in files]
    results: list[dict[str, Any]] = []
    with tqdm(total=len(files), desc=PROG, unit="file", disable=True if args.quiet else None,
              file=sys.stderr) as bar:
        def done(_job: Any, fut: Any) -> None:
            results.append(fut.result())
            bar.update(1)

        try:
            with make_executor(args.scheduler, args.workers) as ex:
                run_all(ex, _batch_one, jobs, on_done=done)
        except RuntimeError as e:
            print(f"{PROG}: error: {e}", file=sys.stderr)
            return 2
    if args.html:
        from reconstruction.report.html import write_index

        write_index(out_dir / "index.html", sorted(results, key=lambda r: r["name"]))
        print(f"{PROG}: HTML reports indexed in {out_dir / 'index.html'}", file=sys.stderr)
    failed = 0
    for r in sorted(results, key=lambda r: r["name"]):
        if r["ok"]:
            print(f"{r['name']}: {r['method']} -> {r['table']}", file=sys.stderr)
        else:
            failed += 1
            print(f"{r['name']}: error: {r['error']}", file=sys.stderr)
    print(f"{PROG}: {len(files) - failed} of {len(files)} reconstructed into {out_dir}", file=sys.stderr)
    return 1 if failed else 0


def np_quiet() -> Any:
    """numpy floating-point warnings off: the checks report bad input; warnings must never reach a user."""

    return np.errstate(all="ignore")


#: OSError numbers that are I/O faults (exit status 1); other OSErrors are about the paths given (status 2).
_IO_FAULTS = frozenset({errno.EIO, errno.ENOSPC, errno.EDQUOT, errno.EFBIG})


def _os_error(e: OSError) -> str:
    where = f"{e.filename}: " if e.filename else ""
    what = e.strerror or str(e)
    if is_no_space(e):
        what += " (the disk is full: free some space and run again; nothing was left half-written)"
    return f"{where}{what}"


def _fmt(x: float | None) -> str:
    return "-" if x is None else f"{x:.3f}"


def main(argv: list[str] | None = None) -> int:
    from reconstruction.cliutil import keep_freed_memory

    keep_freed_memory()
    ap = build_parser()
    args = ap.parse_args(argv)
    from reconstruction.cliutil import plain_warnings

    try:
        with plain_warnings(PROG), np_quiet():
            return _main(ap, args)
    except KeyboardInterrupt:
        print(f"{PROG}: interrupted; nothing was left half-written", file=sys.stderr)
        return 130
    except MemoryError as e:  # numpy's _ArrayMemoryError among them: one line, never a traceback
        print(f"{PROG}: error: {out_of_memory(e)}", file=sys.stderr)
        return 1


def out_of_memory(e: MemoryError) -> str:
    """The one line an out-of-memory says (exit status 1: a resource fault, as a full disk)."""
    what = f" ({shorten(str(e), 120)})" if str(e) else ""
    return f"out of memory{what}; nothing was left half-written: free memory or raise the limit (ulimit -v), run again"


def _main(ap: argparse.ArgumentParser, args: argparse.Namespace) -> int:
    from reconstruction.formats.exports import asks_output, wants_outputs

    if args.batch:
        if args.inputs or args.out or args.preview or args.report or wants_outputs(args):
            ap.error("--batch takes no INPUT, --out, --preview, --report, --rgl, --zemax, --export-mitsuba, "
                     "--export-json, --principled, --materialx, --gltf or --blender (outputs are named after the "
                     "inputs)")
        return run_batch(args)
    if not args.inputs or not (args.out or asks_output(args)):
        ap.error("give INPUT... and --out MATERIAL.binary or another output (--preview, --html, --report, --rgl, "
                 "--zemax, --export-mitsuba, --export-json, --principled, --materialx, --gltf, --blender); or "
                 "--batch FOLDER")
    if args.html is True:
        print(f"{PROG}: error: --html: give the page to write, e.g. --html m.html (a bare --html is for --batch)",
              file=sys.stderr)
        return 2
    try:
        rep = run(args)
    except ImplausibleError as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return EXIT_IMPLAUSIBLE
    except (ReconstructionError, SliceError, MerlError, MaterialError) as e:
        print(f"{PROG}: error: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"{PROG}: error: {_os_error(e)}", file=sys.stderr)
        return 1 if e.errno in _IO_FAULTS else 2
    if not args.quiet:
        checks = rep["checks"]
        failed = [k for k in ("non_negative", "albedo", "reciprocity") if not checks[k]["pass"]]
        model = f" ({rep['details']['model']})" if "model" in rep.get("details", {}) else ""
        o = rep["outputs"]
        written = [f"{o['table']} ({FILE_SIZE:,} bytes)"] if "table" in o else []
        written += [o[k][f] for k, f in (("rgl", "rgl"), ("zemax", "zemax"), ("mitsuba", "xml")) if k in o]
        written += [o["parameters_json"]] if "parameters_json" in o else []
        written += [o[k] if isinstance(o[k], str) else o[k]["file"] for k in ("principled", "materialx", "gltf",
                                                                           "blender") if k in o]
        if "preview" in o:
            written += [o["preview"]["exr"], o["preview"]["png"]]
        written += [o[k] for k in ("report", "html") if k in o]
        print(f"{PROG}: method {rep['method']}{model}: wrote {', '.join(written)}"
              + (f"; IMPLAUSIBLE, written because of --allow-implausible: check(s) failed: {', '.join(failed)}"
                 if failed else "; checks passed" + (f", but see the {len(rep['warnings'])} warning(s) above"
                                                      if rep.get("warnings") else "")),
              file=sys.stderr)
        if "uncertainty" in rep:
            u = rep["uncertainty"]
            ms = u["median_sigma"]
            print(f"{PROG}: uncertainty: median sigma of ln f {_fmt(ms['measured'])} measured, "
                  f"{_fmt(ms['interpolated'])} interpolated, {_fmt(ms['extrapolated'])} extrapolated cells; expect "
                  f"PSNR {u['expected_psnr_db']:.1f} dB, linear image error {u['expected_linear_image_error']:.1%}, "
                  f"cosl2 {u['expected_cosl2']:.1%}"
                  + (f"; in the scene's own images ({u['scene']['name']}): PSNR "
                     f"{u['scene']['expected_scene_psnr_db']:.1f} dB, linear error "
                     f"{u['scene']['expected_scene_linear_error']:.1%}" if "scene" in u else ""), file=sys.stderr)
        if "advice" in rep:
            a = rep["advice"]
            print(f"{PROG}: advice: " + (f"measure theta_i = {a['recommended_theta_i_deg']:g} deg next"
                                         if a["recommended_theta_i_deg"] is not None else a["note"]), file=sys.stderr)
            for cand in a["candidates"]:
                scene_psnr = (f"in the scene {cand['expected_scene_psnr_db']:5.1f} dB, "
                              if "expected_scene_psnr_db" in cand else "")
                print(f"  theta_i {cand['theta_i_deg']:4g} deg: expected PSNR {scene_psnr}"
                      f"{cand['expected_psnr_db']:5.1f} dB (sphere), cosl2 {cand['expected_cosl2']:6.1%}, "
                      f"bench time {cand['bench_time_s']:5.1f} s", file=sys.stderr)
            if "plan" in a:
                p = a["plan"]
                print(f"{PROG}: within {a['budget_s']:g} s: measure "
                      f"{', '.join(f'{x:g}' for x in p['theta_i_deg']) or 'nothing more'} deg "
                      f"({p['bench_time_s']:g} s, expected PSNR {p['expected_psnr_db']:.1f} dB)", file=sys.stderr)
        c = rep.get("conservative")
        if c and c.get("applied"):
            from reconstruction.assess.uncertainty import ANALYTIC_NAME

            ref = "the prior's" if c.get("reference") != ANALYTIC_NAME else f"the {ANALYTIC_NAME}'s"
            print(f"{PROG}: conservative: {c['cells_lowered']:,} of {c['cells']:,} cells no sample rests on lowered to "
                  f"{ref} median x e^({c.get('k', 1):g} sigma) ({c['energy_removed']:.1%} of the table's light; "
                  "--no-conservative keeps the method's extrapolation)", file=sys.stderr)
        if "principled" in rep:
            print(f"{PROG}: {rep['principled']['summary']}", file=sys.stderr)
        if rep.get("colour", {}).get("working_channels") == ["value"]:
            print(f"{PROG}: note: the samples have one band (a photodiode sees one), so the table is grey; a "
                  f"spectrometer bench ([detector] type = \"spectrometer\") or R,G,B columns give colour",
                  file=sys.stderr)
    return 0


if __name__ == "__main__":
    sys.exit(main())
