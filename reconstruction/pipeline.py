"""The reconstruction pipeline: method dispatch (through :mod:`reconstruction.methods`), ``auto``, tabulation of the
result, and :func:`run`, the whole way from input files to a table, a preview and a report (a typed :class:`Job`;
``gonio-reconstruct`` and its ``--batch`` call it).

``auto`` (cross-validation, preferences, margins, prior anchors) is :mod:`reconstruction.methods.auto`.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.base import Reconstruction, ReconstructionError
from reconstruction.core import sharprows
from reconstruction.formats import merl
from reconstruction.formats.inputs import check_slice
from reconstruction.formats.slicefile import Slice
from reconstruction.job import (  # noqa: F401  (the job's names, re-exported: pipeline.Job)
    ImplausibleError,
    Job,
    Progress,
    check_output,
    check_outputs,
    implausible_message,
)
from reconstruction.methods import REGISTRY, Options, get
from reconstruction.methods.auto import KEEP_BUILDS, import_methods, reconstruct_auto, start_child

Array = NDArray[np.float64]

__all__ = ["METHODS", "Options", "reconstruct", "tabulate", "Job", "Progress", "run", "ImplausibleError",
           "check_output", "implausible_message"]

METHODS = ("auto", *REGISTRY)
def reconstruct(s: Slice, method: str = "auto", opts: Options | None = None,
                progress: Callable[[str], None] | None = None) -> tuple[Reconstruction, dict[str, Any]]:
    """Reconstruct ``s`` (f_r, grey or RGB) with ``method`` (``auto`` or a registered name); returns
    (reconstruction, choice) where choice holds ``requested``, ``used``, ``reason`` (and ``cross_validation``
    for ``auto``)."""
    opts = opts or Options()
    check_slice(s)  # too few samples, NaN/inf, all zero, duplicates: a clear error before any method runs
    s = s.sorted()  # by (theta_i, theta_o): the order the methods expect (captures may be in any order)
    if method == "auto":
        return reconstruct_auto(s, opts, progress)
    rec = get(method).build(s, opts, progress)
    return rec, {"requested": method, "used": rec.method, "reason": f"requested with --method {method}"}


def tabulate(rec: Reconstruction, supersample: tuple[int, int, int] | str | None = None,
             info: dict[str, Any] | None = None) -> Array:
    """The MERL table (3, 90, 90, 180) of ``rec``: bin-centre values, or cell averages with ``supersample``
    ((nh, nd, np) or "adaptive", see :func:`reconstruction.formats.merl.tabulate`).

    Uses the method's own fast ``table()`` for bin centres when it has one; otherwise ``merl.tabulate``. Where the
    method names a lobe narrower than the cells (``sharp_theta_h_rad``), the rows holding it are cell averages over
    theta_h, each theta_d row scaled to the lobe's energy as table readers see it
    (:func:`reconstruction.core.sharprows.renormalise`; its figures go into ``info`` when given).
    Raises :class:`ReconstructionError` if a cell above the horizon is not finite or is negative.
    """
    fast = getattr(rec, "table", None)
    sharp = getattr(rec, "sharp_theta_h_rad", None)  # a lobe narrower than the cells near theta_h = 0
    if supersample is None and callable(fast):
        t = fast()  # the method's own table (its own theta_h cell averages where a lobe is sharper than the cells)
    else:
        t = merl.tabulate(rec.eval, supersample=supersample)
        if supersample is None and sharp:
            t, _ = merl.average_theta_h_cells(rec.eval, t, sharp, n=8)
    if supersample is None and sharp:  # those rows keep the lobe's energy as table readers see it
        t, figures = sharprows.renormalise(rec.eval, t, sharp)
        if info is not None:
            info.update(figures)
    valid = merl.valid_mask()[None]
    bad = valid & ~np.isfinite(t)
    if bad.any():
        raise ReconstructionError(f"method {rec.method}: {int(bad.sum())} table cell(s) above the horizon have no "
                                  f"finite value")
    neg = valid & (t < 0)
    if neg.any():
        raise ReconstructionError(f"method {rec.method}: {int(neg.sum())} table cell(s) are negative (min "
                                  f"{float(t[neg].min()):.3g})")
    return t


# --- the end-to-end pipeline: input files -> table, preview, report ---------------------------------------------


def run(job: Job, progress: Progress | None = None) -> dict[str, Any]:
    """Reconstruct ``job``: read and merge the inputs, convert colour, reconstruct with the job's method (through
    the registry), tabulate, check plausibility, write the table (atomically), the preview and the report.
    Returns the report. Raises :class:`ImplausibleError` (nothing written) for a table that fails a plausibility
    check unless ``job.allow_implausible``; bad input is a :class:`ReconstructionError` (or a reader's error)
    naming the file, checked output paths before any work. The job's fits (auto's folds, the HTML report's other
    methods) share their cone integrals (:func:`reconstruction.bench.instrument.shared_cone_averages`). With the
    uncertainty or the HTML page asked and a second core, what they need that does not wait for the main thread
    runs beside it in a helper thread (:class:`reconstruction.executor.Background`): the built-in family's
    posterior (the samples' alone) while the samples are reconstructed, matplotlib's imports while the table is
    tabulated, checked and written; in another, the page's sphere renders from the tabulation on (again if a
    fallback or the conservative bound changes the table); the page's other figures are drawn in forked
    children (:func:`reconstruction.report.figures.beside`)."""
    from contextlib import nullcontext

    from threadpoolctl import threadpool_limits

    from reconstruction.bench.instrument import seed_shared_cone_averages, shared_cone_averages
    from reconstruction.executor import Background, Forked

    # the built-in family's posterior beside the reconstruction: one BLAS thread for the whole run, so that the
    # limits fit sets and lifts around its own solves (process-wide) never change the posterior's threads midway
    from reconstruction.report.figures import Drawer

    blas = threadpool_limits(1, user_api="blas") if job.posterior_early else nullcontext()
    # the page's drawer and auto's child for the cross-validation of the methods that do not wait for fit first:
    # they are forked before any thread of the run starts and before scipy is imported (half a second): the drawer
    # imports matplotlib meanwhile, auto's child computes fit's cone tables of the samples and imports the methods
    with Drawer(enabled=bool(job.html)) as drawer:
        child = Forked(enabled=job.method == "auto")
        seed = (start_child(child, job.inputs, job.quantity, job.columns, job.blind_spot_deg, job.angles_in)
                if child.alive else None)
        if job.method == "auto":
            import_methods()
        with child, blas, shared_cone_averages(), Background(enabled=job.assesses or job.bounds) as helper, \
                Background(enabled=bool(job.html)) as renders:
            if seed is not None:
                seed_shared_cone_averages(seed())
            return _run(job, progress, helper, renders, drawer)


class _Steps:
    """The run's named steps: each begun (shown on the progress bar) and done (its time in ``timings``, s)."""

    def __init__(self, progress: Progress | None) -> None:
        self.progress = progress
        self.timings: dict[str, float] = {}

    def begin(self, label: str) -> float:
        if self.progress is not None:
            self.progress.begin(label)
        return time.perf_counter()

    def done(self, step: str, t0: float) -> None:
        self.timings[step] = time.perf_counter() - t0
        if self.progress is not None:
            self.progress.done(step)


def _run(job: Job, progress: Progress | None, helper: Any, renders: Any, drawer: Any) -> dict[str, Any]:
    """Read, reconstruct, tabulate, check, bound, write and report: the run's steps in order."""
    check_outputs(job)
    steps = _Steps(progress)
    loaded, scene = _read_inputs(job, steps)
    working, colour_info = _to_working(job, loaded, steps, drawer)
    rec, choice, opts, early, others = _reconstruct_step(job, steps, working, scene, helper, drawer)
    drawn_for = rec  # the reconstruction the sample figures were sent for
    rec, table, checks, energy, bounded, ref = _table_step(job, steps, rec, choice, working, opts, early)
    spheres = None
    if job.html:  # the page's sphere renders (numpy) in a thread of their own, from now to the page's drawing
        from reconstruction.report.html import draw_table_figures
        from reconstruction.report.spheres import sphere_images

        spheres = renders.submit(sphere_images, np.asarray(table, dtype=np.float64), checks["albedo"])
        if rec is not drawn_for:  # a fallback or the bounded reconstruction: its figures sent again
            others = _send_sample_figures(job, drawer, working, rec, choice, opts, others)
        draw_table_figures(drawer, working.sorted(), table, checks)  # the final table's
    outputs, principled, ref = _write_step(job, steps, rec, table, working, early, ref)
    rep = _report(job, steps, loaded, scene, rec, choice, working, table, checks, colour_info, energy, outputs)
    if principled is not None:
        rep["principled"] = principled
    _warn(rep, loaded.files)
    if bounded is not None:
        rep["conservative"] = bounded
    sigma_table = None
    if job.assesses:
        t0 = steps.begin("uncertainty")
        sigma_table = _assess(job, rep, working, rec, opts, steps.begin, steps.done,
                              ref if ref is not None or early is None else early()[0],
                              getattr(loaded, "capture", None) or {})
        steps.done("uncertainty", t0)
    _finish(job, steps, rep, outputs, checks, working, rec, table, others, choice, sigma_table, spheres, drawer)
    return rep


def _read_inputs(job: Job, steps: _Steps) -> tuple[Any, Any]:
    """The inputs (``inputs.Loaded``: the slice, files, quantities, notes) and the scene (or None)."""
    from reconstruction.core.scene import load_scene
    from reconstruction.formats import brdffile, inputs, zemax
    from reconstruction.schema.files import UserFileError, check_user_file

    t0 = steps.begin("reading inputs")
    loaded = zemax.load_inputs(list(job.inputs), job.quantity, job.columns) or brdffile.load_inputs(
        list(job.inputs), job.quantity, job.columns) or inputs.load_inputs(
        list(job.inputs), quantity=job.quantity, columns=inputs.parse_columns(job.columns),
        blind_spot_deg=job.blind_spot_deg, angles_in=job.angles_in)
    scene = None
    if job.scene:
        sp = Path(job.scene)
        try:
            check_user_file(sp, "a scene file (TOML)")
        except UserFileError as e:
            if e.kind in ("directory", "special"):  # a device or a pipe would block the read
                raise ReconstructionError(f"--scene {sp}: not a regular file, expected a scene file (TOML)") from None
        try:
            scene = load_scene(sp)
        except RecursionError:
            raise ReconstructionError(f"--scene {sp}: invalid TOML: nested too deeply") from None
    steps.done("read", t0)
    return loaded, scene


def _to_working(job: Job, loaded: Any, steps: _Steps, drawer: Any) -> tuple[Slice, dict[str, Any]]:
    """The samples in the working channels (grey or linear RGB) and what the colour conversion did."""
    from reconstruction.core import colour

    t0 = steps.begin("colour")
    try:
        working, colour_info = colour.to_working_channels(loaded.slice, job.illuminant)
    except ReconstructionError as e:  # e.g. spectral channels outside the observer: say which input
        raise ReconstructionError(f"{', '.join(loaded.files)}: {e}") from None
    steps.done("colour", t0)
    name = working.meta.get("material") or material_of(loaded.files)
    if name and "material" not in working.meta:  # the merged inputs keep no metadata: the name is the files'
        working = replace(working, meta={**working.meta, "material": name})
    if job.html:  # the page's figure of the samples alone, drawn by its child while they are reconstructed
        from reconstruction.report.html import draw_polar_figure

        draw_polar_figure(drawer, working)
    return working, colour_info


def _reconstruct_step(job: Job, steps: _Steps, working: Slice, scene: Any, helper: Any, drawer: Any
                      ) -> tuple[Reconstruction, dict[str, Any], Options, Any, dict[str, Any]]:
    """The chosen method's reconstruction, auto's choice, the options, the early posterior's future (or None) and
    the page's other methods."""
    from reconstruction.core.scene import LOBE_KINDS
    from reconstruction.executor import SpareCore

    lobes = list(job.lobes) if job.lobes else None
    if lobes:
        unknown = [x for x in lobes if x not in LOBE_KINDS]
        if unknown:
            raise ReconstructionError(f"--lobes: unknown kind(s) {unknown}; expected {', '.join(LOBE_KINDS)}")
    t0 = steps.begin("reconstructing")
    opts = Options(scene=scene, **{**job.method_options(), "lobes": lobes})
    early = None
    # auto cross-validates the methods that do not wait for fit beside it (in its forked child, or a thread of its
    # own): the posterior below waits until that is done (a third busy worker on two cores would slow fit, the
    # critical path)
    spare = SpareCore(hold=job.method == "auto")
    if job.posterior_early:  # the built-in family's posterior (and auto's bound from it) depend on the samples alone
        early = helper.submit(spare.later(_early_reference), working.sorted(), job.bounds)
    keep = KEEP_BUILDS.set(bool(job.html))  # the page draws every method: auto's child builds its own
    progress = steps.progress
    try:
        with spare:
            rec, choice = reconstruct(working, job.method, opts,
                                      progress=(lambda name: progress.begin(f"fitting {name}")) if progress else None)
    finally:
        KEEP_BUILDS.reset(keep)
    steps.done("reconstruct", t0)
    built = choice.pop("built", None)  # auto's forked child's builds of its methods (with the page)
    others: dict[str, Any] = {}
    if job.html:  # the page's figures of the samples and methods, drawn by its child while the run goes on
        others = _send_sample_figures(job, drawer, working, rec, choice, opts, built=built() if built else None)
    return rec, choice, opts, early, others


def _table_step(job: Job, steps: _Steps, rec: Reconstruction, choice: dict[str, Any], working: Slice, opts: Options,
                early: Any) -> tuple[Reconstruction, Array, dict[str, Any], dict[str, Any], Any, Any]:
    """Tabulate, check (falling back when auto has fallbacks), bound where no sample rests: (rec, table, checks,
    energy, the conservative section or None, the posterior reference or None)."""
    from reconstruction.report import summary as report

    t0 = steps.begin("tabulating" + (f" (supersample {job.supersample})" if job.supersample else ""))
    energy: dict[str, Any] = {}
    table = tabulate(rec, job.supersample, energy)
    steps.done("tabulate", t0)
    t0 = steps.begin("plausibility checks")
    checks = report.plausibility(rec, table)
    fallbacks = choice.pop("fallbacks", None)
    if not checks["all_pass"] and not job.allow_implausible and fallbacks is not None:
        rec, table, checks, energy = _fall_back(job, (rec, table, checks, energy), choice, fallbacks, steps.progress)
    steps.done("checks", t0)
    if not checks["all_pass"] and not job.allow_implausible:
        raise ImplausibleError(implausible_message(rec.method, checks))
    ref, bounded = None, None
    if job.bounds:
        t0 = steps.begin("conservative bound")
        rec, table, bounded, ref = bound_where_unmeasured(
            rec, table, working, opts, *(early() if early is not None else ()))
        if bounded["applied"]:
            checks = report.plausibility(rec, table)  # of the table written (only lowered: still passing)
        steps.done("conservative", t0)
    return rec, table, checks, energy, bounded, ref


def _write_step(job: Job, steps: _Steps, rec: Reconstruction, table: Array, working: Slice, early: Any, ref: Any
                ) -> tuple[dict[str, Any], Any, Any]:
    """Write the table, the exports, the preview and the principled material: (outputs, principled section or
    None, the posterior reference)."""
    from reconstruction.formats import exports, merl
    from reconstruction.principled.outputs import wants as wants_principled
    from reconstruction.principled.outputs import write_outputs as write_principled
    from reconstruction.report import preview

    out = Path(job.out) if job.out else None
    t0 = steps.begin("writing table")
    outputs: dict[str, Any] = {}
    if out is not None:
        merl.write(out, table, require_above_horizon=True)
        outputs.update({"table": str(out), "table_bytes": out.stat().st_size})
    outputs.update(exports.write_outputs(job, rec, steps.timings))
    steps.done("write", t0)
    if job.preview:
        t0 = steps.begin("preview")
        outputs["preview"] = (exports.mitsuba_preview(job, rec, outputs) if job.preview_renderer == "mitsuba"
                              else preview.write_preview(job.preview, table))
        steps.done("preview", t0)
    principled = None
    if wants_principled(job):
        if early is not None:  # its fit sets the process's BLAS threads, as the posterior does: one at a time
            ref = early()[0]
        t0 = steps.begin("principled material")
        files, principled = write_principled(job, rec, _name(job, working))
        outputs.update(files)
        steps.done("principled", t0)
    return outputs, principled, ref


def _report(job: Job, steps: _Steps, loaded: Any, scene: Any, rec: Reconstruction, choice: dict[str, Any],
            working: Slice, table: Array, checks: dict[str, Any], colour_info: dict[str, Any],
            energy: dict[str, Any], outputs: dict[str, Any]) -> dict[str, Any]:
    """The JSON report's body (docs/formats.md)."""
    from reconstruction.formats import merl
    from reconstruction.report import summary as report

    return report.build_report(
        rec=rec, choice=choice, working=working, table=table, checks=checks,
        inputs={"files": loaded.files, "quantities": loaded.quantities, "notes": loaded.notes,
                "columns": job.columns, "scene": job.scene,
                **({"scene_ranges_deg": {"theta_i": scene.theta_i_deg, "theta_o": scene.theta_o_deg},
                    **({"scene_view": scene.view} if scene.view else {})} if scene is not None else {})},
        colour=colour_info,
        table_info={"cells": 3 * merl.N_CELLS,
                    "values": "cell averages" if job.supersample else getattr(rec, "table_values", "bin centres")
                    + ("; " + sharprows.DESCRIPTION if energy else ""),
                    **({"sharp_rows": energy} if energy else {}),
                    "supersample": (list(job.supersample) if isinstance(job.supersample, tuple)
                                    else job.supersample),
                    "bin_centres": "theta_h = ((i + 0.5) / 90)^2 * 90 deg, theta_d = j + 0.5 deg, "
                                   "phi_d = k + 0.5 deg"},
        outputs=outputs, timings=steps.timings, dropped_blind_spot=loaded.dropped_blind_spot)


def _warn(rep: dict[str, Any], files: list[str]) -> None:
    """Say what the samples cannot support (:func:`reconstruction.report.summary.guard_warnings`): as warnings
    (one line each on the console) and in the report's ``warnings``."""
    import warnings

    from reconstruction.report.summary import guard_warnings

    said = guard_warnings(rep["coverage"], rep.get("cross_validation"), ", ".join(files), rep.get("method"),
                          rep.get("parameters"))
    for msg in said:
        warnings.warn(msg, UserWarning, stacklevel=2)
    if said:
        rep["warnings"] = said


def _finish(job: Job, steps: _Steps, rep: dict[str, Any], outputs: dict[str, Any], checks: dict[str, Any],
            working: Slice, rec: Reconstruction, table: Array, others: dict[str, Any], choice: dict[str, Any],
            sigma_table: Any, spheres: Any, drawer: Any) -> None:
    """The report's last words, the JSON report and the HTML page written."""
    from reconstruction.report import summary as report

    if not checks["all_pass"]:
        rep["implausible_table_written"] = "written with --allow-implausible: " + implausible_message(rec.method,
                                                                                                      checks)
    if job.html:
        outputs["html"] = str(job.html)
        rep["outputs"]["html"] = str(job.html)
    if job.report:
        outputs["report"] = str(job.report)
        rep["outputs"]["report"] = str(job.report)
        report.write_json(job.report, rep)
    if job.html:
        t0 = steps.begin("html report")
        _write_html(job, rep, working, rec, table, others, choice, sigma_table, spheres, drawer)
        rep["timings_s"]["html"] = round(time.perf_counter() - t0, 4)
        steps.done("html", t0)


def _fall_back(job: Job, first: tuple[Reconstruction, Array, dict[str, Any], dict[str, Any]], choice: dict[str, Any],
               fallbacks: Callable[[], Any], progress: Progress | None
               ) -> tuple[Reconstruction, Array, dict[str, Any], dict[str, Any]]:
    """auto's chosen method wrote an implausible table (``first``: its reconstruction, table, checks and the
    tabulation's notes): the next methods in auto's order, the first whose table passes every check (``choice``
    says so); ``first`` when none does (then refused as before)."""
    from reconstruction.report import summary as report

    rec, checks = first[0], first[2]
    failed = implausible_message(rec.method, checks)
    for label, alt in fallbacks():
        if progress is not None:
            progress.begin(f"falling back to {label}")
        energy: dict[str, Any] = {}
        table = tabulate(alt, job.supersample, energy)
        c = report.plausibility(alt, table)
        if c["all_pass"]:
            choice["used"] = alt.method
            choice["reason"] += f"; not written: {failed}; written instead: {label}, the next in auto's order"
            cv = choice.get("cross_validation", {})
            cv.update({"chosen": alt.method, "chosen_label": label, "fell_back_from": rec.method})
            return alt, table, c, energy
    return first


def _early_reference(s: Slice, bounds: bool) -> tuple[Any, Array | None]:
    """(the built-in analytic family's posterior of the samples ``s`` (sorted), with ``bounds`` its upper bound
    table for auto's table (:func:`reconstruction.assess.guard.upper_bound_table`) else None): what the run's
    helper thread computes beside the reconstruction."""
    from reconstruction.assess import guard
    from reconstruction.assess.uncertainty import reference_posterior

    ref = reference_posterior(s)
    return ref, (guard.upper_bound_table(ref, guard.GUARD_SIGMAS_ANALYTIC) if bounds else None)


def bound_where_unmeasured(rec: Reconstruction, table: Array, working: Slice, opts: Options, ref: Any = None,
                           bound: Array | None = None) -> tuple[Reconstruction, Array, dict[str, Any], Any]:
    """``auto``'s table kept below the reference posterior's upper credible bound where no sample rests
    (:mod:`reconstruction.assess.guard`): the prior's with ``--prior``; without, the built-in analytic family's
    (looser, and only where it takes a large share of the light). Returns (the bounded reconstruction, its
    table, the report's ``conservative`` section, the reference posterior); ``ref``: the analytic family's
    posterior of the samples when computed already, ``bound`` its upper bound table if computed too. The
    benchmarks call this as the pipeline does."""
    from reconstruction.assess import guard, uncertainty

    s = working.sorted()
    if ref is None or opts.prior or uncertainty._own_posterior(rec) is not None:
        ref, bound = uncertainty.reference_for(rec, s, opts.prior, tuple(opts.prior_exclude)), None
    if opts.prior:
        bounded, out, info = guard.conservative(rec, table, s, ref)
    else:
        bounded, out, info = guard.conservative(rec, table, s, ref, guard.GUARD_SIGMAS_ANALYTIC,
                                                guard.ANALYTIC_MIN_ENERGY, guard.ANALYTIC_MAX_ABOVE, bound=bound)
    # nothing lowered: the method's own reconstruction stays (an analytic fit exports its lobes); else the bounded
    # one, which every output sees (its table is no longer the model's: exports treat it as data-driven)
    return (bounded if info["applied"] else rec), out, info, ref


def _assess(job: Job, rep: dict[str, Any], working: Slice, rec: Reconstruction, opts: Options,
            begin: Callable[[str], float], done: Callable[[str, float], None], ref: Any = None,
            capture: dict[str, Any] | None = None) -> NDArray[np.float32]:
    """The report's ``uncertainty`` (and the ``--uncertainty`` array) and, with ``--advise``, its ``advice`` (the
    bench of ``--bench``, else the one the slice file records: ``capture``, ``inputs.LoadedInput.capture``);
    returns sigma of ln f per cell (3, 90, 90, 180)."""
    from reconstruction.assess import advice, uncertainty
    from reconstruction.atomic import atomic_path

    s = working.sorted()
    sigma, section, ref, sg, f_grid = uncertainty.assess_table(rec, s, opts.prior, tuple(opts.prior_exclude), ref,
                                                               scene=opts.scene)
    if job.uncertainty:
        with atomic_path(job.uncertainty) as tmp:
            with open(tmp, "wb") as fh:
                np.save(fh, sigma)
        section["file"] = str(job.uncertainty)
        rep["outputs"]["uncertainty"] = str(job.uncertainty)
    rep["uncertainty"] = section
    if job.advise:
        t0 = begin("advice")
        limits = (advice.bench_limits(job.bench) if job.bench or not capture
                  else advice.capture_limits(capture["meta"], capture["file"]) or advice.BenchLimits())
        rep["advice"] = advice.advise(s, ref, limits, job.budget_s,
                                      current={**{k: section[k] for k in ("expected_psnr_db", "expected_cosl2",
                                                                          "expected_linear_image_error")},
                                               **{k: v for k, v in section.get("scene", {}).items()
                                                  if k.startswith("expected_")}},
                                      sigma_now=sg, f_grid=f_grid, scene=opts.scene)
        done("advice", t0)
    return sigma


def material_of(files: list[str]) -> str | None:
    """The material the input slice files name in their metadata (``# meta: {"material": ...}``), when they all
    name the same one; else None."""
    import json

    names = set()
    for f in files:
        try:
            with open(f, encoding="utf-8", errors="replace") as fh:
                head = [fh.readline(), fh.readline()]
        except OSError:
            return None
        if not (head[0].startswith("# gonio-brdf slice") and head[1].startswith("# meta: ")):
            return None
        try:
            name = json.loads(head[1][len("# meta: "):]).get("material")
        except (ValueError, AttributeError):
            return None
        names.add(name if isinstance(name, str) and name else None)
    return names.pop() if len(names) == 1 else None


def _name(job: Job, working: Slice) -> str:
    """The material's name: the slice's, else the stem of the first output file."""
    return str(working.meta.get("material") or Path(job.out or job.html or job.principled or job.materialx
                                                    or job.gltf or job.blender or "material").stem)


def _other_methods(working: Slice, rec: Reconstruction, opts: Options,
                   built: dict[str, Reconstruction] | None = None) -> dict[str, Reconstruction]:
    """Every other registered method built on the same samples (the page draws their predictions); ``built``:
    those built already (by auto's forked child)."""
    ordered = working.sorted()
    others: dict[str, Reconstruction] = {}
    for name, m in REGISTRY.items():
        if name != rec.method:
            try:
                others[name] = built[name] if built and name in built else m.build(ordered, opts, None)
            except (ReconstructionError, ValueError):
                pass
    return others


def _send_sample_figures(job: Job, drawer: Any, working: Slice, rec: Reconstruction, choice: dict[str, Any],
                         opts: Options, others: dict[str, Reconstruction] | None = None,
                         built: dict[str, Reconstruction] | None = None) -> dict[str, Reconstruction]:
    """The page's slices and polar figures sent to its drawer (:func:`reconstruction.report.html.
    draw_sample_figures`); returns the other methods built for them (``others``, those built for an earlier
    reconstruction of the same method, reused: the bound changes the reconstruction, not the method; ``built``,
    those auto's forked child built)."""
    from reconstruction.report.html import draw_sample_figures

    if others is None or rec.method in others:  # the first time, or a fallback to one of them
        others = _other_methods(working, rec, opts, built)
    draw_sample_figures(drawer, working.sorted(), rec, others,
                        choice.get("held_out_predictions", {}).get(rec.method), job.blind_spot_deg or 4.0)
    return others


def _write_html(job: Job, rep: dict[str, Any], working: Slice, rec: Reconstruction, table: Array,
                others: dict[str, Reconstruction], choice: dict[str, Any], sigma: NDArray[np.float32] | None = None,
                spheres: Callable[[], Any] | None = None, drawer: Any = None) -> None:
    """The HTML report of ``job``: ``others``, every other registered method built on the same samples;
    ``spheres``: the sphere renders under way (:func:`reconstruction.report.spheres.sphere_images`); ``drawer``:
    the run's :class:`~reconstruction.report.figures.Drawer`, the sample figures sent."""
    from reconstruction.report import html as htmlreport

    htmlreport.write_html(job.html, report=rep, working=working.sorted(), rec=rec, table=table, alternatives=others,
                          held_out=choice.get("held_out_predictions", {}).get(rec.method), title=_name(job, working),
                          sigma=sigma, spheres=spheres, drawer=drawer)
