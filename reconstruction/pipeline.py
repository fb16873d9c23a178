"""The reconstruction pipeline: method dispatch (through :mod:`reconstruction.methods`), ``auto``, tabulation of the
result, and :func:`run`, the whole way from input files to a table, a preview and a report (a typed :class:`Job`;
``gonio-reconstruct`` and its ``--batch`` call it).

``auto`` (cross-validation, preferences, margins, prior anchors) is :mod:`reconstruction.methods.auto`.
"""

from __future__ import annotations

import json
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.assess import advice, guard, uncertainty
from reconstruction.atomic import atomic_path
from reconstruction.base import Reconstruction, ReconstructionError
from reconstruction.core import colour, merlgrid, merltable, sharprows
from reconstruction.core.checks import plausibility
from reconstruction.core.scene import load_scene
from reconstruction.core.slicedata import Slice
from reconstruction.formats import brdffile, exports, inputs, merl, zemax
from reconstruction.formats.inputs import check_slice
from reconstruction.job import (
    ImplausibleError,
    Job,
    Progress,
    check_outputs,
    implausible_message,
)
from reconstruction.methods import REGISTRY, Options, get
from reconstruction.methods.auto import reconstruct_auto
from reconstruction.principled.outputs import wants as wants_principled
from reconstruction.principled.outputs import write_outputs as write_principled
from reconstruction.report import html as htmlreport
from reconstruction.report import preview, summary
from reconstruction.report.spheres import sphere_images
from reconstruction.schema.scene import LOBE_KINDS
from reconstruction.workers import Workers

Array = NDArray[np.float64]

__all__ = ["METHODS", "reconstruct", "tabulate", "run", "Made", "bound_where_unmeasured", "material_of"]

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
    ((nh, nd, np) or "adaptive", see :func:`reconstruction.core.merltable.tabulate`).

    Uses the method's own fast ``table()`` for bin centres when it has one; otherwise ``merltable.tabulate``. Where the
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
        t = merltable.tabulate(rec.eval, supersample=supersample)
        if supersample is None and sharp:
            t, _ = merltable.average_theta_h_cells(rec.eval, t, sharp, n=8)
    if supersample is None and sharp:  # those rows keep the lobe's energy as table readers see it
        t, figures = sharprows.renormalise(rec.eval, t, sharp)
        if info is not None:
            info.update(figures)
    valid = merlgrid.valid_mask()[None]
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
    methods) share their cone integrals (:func:`reconstruction.instrument.response.shared_cone_averages`). With the
    uncertainty or the HTML page asked and a second core, what they need that does not wait for the main thread
    runs beside it (:class:`reconstruction.workers.Workers`): the built-in family's posterior (the samples' alone)
    while the samples are reconstructed, matplotlib's imports while the table is tabulated, checked and written;
    in another thread, the page's sphere renders from the tabulation on (again if a fallback or the conservative
    bound changes the table); the page's other figures are drawn in forked children
    (:class:`reconstruction.report.figures.Drawer`)."""
    check_outputs(job)
    with Workers.start(job) as workers:
        steps = _Steps(job, progress, workers)
        made = _load(steps)
        made = _reconstruct(steps, made)
        made = _check(steps, made)
        made = _write(steps, made)
        return _report(steps, made)


@dataclass(frozen=True)
class Made:
    """What the run's steps have made so far: each step is given it and returns a copy with its own part.

    ``_load``: ``loaded`` (:class:`reconstruction.formats.inputs.Loaded`: the slice, files, quantities, notes),
    ``scene`` (or None), ``working`` (the samples in the working channels, grey or linear RGB) and ``colour``
    (what the colour conversion did). ``_reconstruct``: ``rec``, ``choice`` (auto's), ``opts``, ``early`` (the
    built-in family's posterior under way, or None) and ``others`` (the page's other methods). ``_check``:
    ``table`` (3, 90, 90, 180), ``checks``, ``energy`` (the sharp rows' figures), ``bounded`` (the conservative
    section, or None), ``ref`` (the posterior reference, or None) and ``spheres`` (the page's sphere renders under
    way, or None). ``_write``: ``outputs`` and ``principled`` (its report section, or None)."""

    loaded: Any
    scene: Any
    working: Slice
    colour: dict[str, Any]
    rec: Reconstruction | None = None
    choice: dict[str, Any] = field(default_factory=dict)
    opts: Options = field(default_factory=Options)
    early: Callable[[], Any] | None = None
    others: dict[str, Reconstruction] = field(default_factory=dict)
    table: Array | None = None
    checks: dict[str, Any] = field(default_factory=dict)
    energy: dict[str, Any] = field(default_factory=dict)
    bounded: dict[str, Any] | None = None
    ref: Any = None
    spheres: Callable[[], Any] | None = None
    outputs: dict[str, Any] = field(default_factory=dict)
    principled: dict[str, Any] | None = None

    @property
    def reference(self) -> Any:
        """The posterior reference: the one computed already, else the early one (waited for), else None."""
        return self.ref if self.ref is not None or self.early is None else self.early()[0]


class _Steps:
    """The run's job, its workers and its named steps: each begun (shown on the progress bar) and done (its time in
    ``timings``, s)."""

    def __init__(self, job: Job, progress: Progress | None, workers: Workers) -> None:
        self.job = job
        self.progress = progress
        self.workers = workers
        self.timings: dict[str, float] = {}

    def begin(self, label: str) -> float:
        if self.progress is not None:
            self.progress.begin(label)
        return time.perf_counter()

    def done(self, step: str, t0: float) -> None:
        self.timings[step] = time.perf_counter() - t0
        if self.progress is not None:
            self.progress.done(step)


def _load(steps: _Steps) -> Made:
    """The inputs and the scene read, the samples in the working channels (grey or linear RGB)."""
    job = steps.job
    t0 = steps.begin("reading inputs")
    loaded = zemax.load_inputs(list(job.inputs), job.quantity, job.columns) or brdffile.load_inputs(
        list(job.inputs), job.quantity, job.columns) or inputs.load_inputs(
        list(job.inputs), quantity=job.quantity, columns=inputs.parse_columns(job.columns),
        blind_spot_deg=job.blind_spot_deg, angles_in=job.angles_in)
    scene = _read_scene(Path(job.scene)) if job.scene else None
    steps.done("read", t0)
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
        htmlreport.draw_polar_figure(steps.workers.drawer, working)
    return Made(loaded=loaded, scene=scene, working=working, colour=colour_info)


def _read_scene(sp: Path) -> Any:
    """The scene file of ``--scene`` (:func:`reconstruction.core.scene.load_scene`), its errors worded for the
    flag."""
    try:
        return load_scene(sp)  # the one user-file check (type, size, UTF-8) is inside it
    except RecursionError:
        raise ReconstructionError(f"--scene {sp}: invalid TOML: nested too deeply") from None


def _reconstruct(steps: _Steps, made: Made) -> Made:
    """The chosen method's reconstruction (auto's choice), the early posterior under way, the page's other
    methods."""
    job = steps.job
    lobes = list(job.lobes) if job.lobes else None
    if lobes:
        unknown = [x for x in lobes if x not in LOBE_KINDS]
        if unknown:
            raise ReconstructionError(f"--lobes: unknown kind(s) {unknown}; expected {', '.join(LOBE_KINDS)}")
    t0 = steps.begin("reconstructing")
    opts = Options(scene=made.scene, **{**job.method_options(), "lobes": lobes})
    progress = steps.progress
    with steps.workers.reconstructing(_early_reference, made.working.sorted(), job.bounds) as early:
        rec, choice = reconstruct(made.working, job.method, opts,
                                  progress=(lambda name: progress.begin(f"fitting {name}")) if progress else None)
    steps.done("reconstruct", t0)
    built = choice.pop("built", None)  # auto's forked child's builds of its methods (with the page)
    made = replace(made, rec=rec, choice=choice, opts=opts, early=early)
    if job.html:  # the page's figures of the samples and methods, drawn by its child while the run goes on
        made = replace(made, others=_send_sample_figures(job, steps.workers.drawer, made.working, rec, choice, opts,
                                                         built=built() if built else None))
    return made


def _check(steps: _Steps, made: Made) -> Made:
    """Tabulate, check (falling back when auto has fallbacks), bound where no sample rests; the page's sphere
    renders and table figures started."""
    job = steps.job
    rec = made.rec
    assert rec is not None
    t0 = steps.begin("tabulating" + (f" (supersample {job.supersample})" if job.supersample else ""))
    energy: dict[str, Any] = {}
    table = tabulate(rec, job.supersample, energy)
    steps.done("tabulate", t0)
    t0 = steps.begin("plausibility checks")
    checked = replace(made, table=table, checks=plausibility(rec, table), energy=energy)
    fallbacks = made.choice.pop("fallbacks", None)
    if not checked.checks["all_pass"] and not job.allow_implausible and fallbacks is not None:
        checked = _fall_back(steps, checked, fallbacks)
    steps.done("checks", t0)
    if not checked.checks["all_pass"] and not job.allow_implausible:
        raise ImplausibleError(implausible_message(checked.rec.method, checked.checks))
    if job.bounds:
        t0 = steps.begin("conservative bound")
        bounded_rec, bounded_table, bounded, ref = bound_where_unmeasured(
            checked.rec, checked.table, made.working, made.opts,
            *(made.early() if made.early is not None else ()))
        checked = replace(checked, rec=bounded_rec, table=bounded_table, bounded=bounded, ref=ref)
        if bounded["applied"]:  # of the table written (only lowered: still passing)
            checked = replace(checked, checks=plausibility(bounded_rec, bounded_table))
        steps.done("conservative", t0)
    if job.html:  # the page's sphere renders (numpy) in a thread of their own, from now to the page's drawing
        checked = _start_page(steps, checked, drawn_for=rec)
    return checked


def _fall_back(steps: _Steps, made: Made, fallbacks: Callable[[], Any]) -> Made:
    """auto's chosen method wrote an implausible table (``made``: its reconstruction, table, checks and the
    tabulation's notes): the next methods in auto's order, the first whose table passes every check (its
    ``choice`` says so); ``made`` when none does (then refused as before)."""
    rec, choice = made.rec, made.choice
    assert rec is not None
    failed = implausible_message(rec.method, made.checks)
    for label, alt in fallbacks():
        if steps.progress is not None:
            steps.progress.begin(f"falling back to {label}")
        energy: dict[str, Any] = {}
        table = tabulate(alt, steps.job.supersample, energy)
        c = plausibility(alt, table)
        if c["all_pass"]:
            choice["used"] = alt.method
            choice["reason"] += f"; not written: {failed}; written instead: {label}, the next in auto's order"
            cv = choice.get("cross_validation", {})
            cv.update({"chosen": alt.method, "chosen_label": label, "fell_back_from": rec.method})
            return replace(made, rec=alt, table=table, checks=c, energy=energy)
    return made


def _start_page(steps: _Steps, made: Made, drawn_for: Reconstruction) -> Made:
    """The page's sphere renders started in their thread, the sample figures sent again if the reconstruction is
    no longer ``drawn_for`` (a fallback or the bounded reconstruction), the final table's figures sent."""
    drawer, rec = steps.workers.drawer, made.rec
    assert rec is not None
    spheres = steps.workers.renders.submit(sphere_images, np.asarray(made.table, dtype=np.float64),
                                           made.checks["albedo"])
    others = made.others
    if rec is not drawn_for:  # a fallback or the bounded reconstruction: its figures sent again
        others = _send_sample_figures(steps.job, drawer, made.working, rec, made.choice, made.opts, others)
    htmlreport.draw_table_figures(drawer, made.working.sorted(), made.table, made.checks)  # the final table's
    return replace(made, spheres=spheres, others=others)


def _write(steps: _Steps, made: Made) -> Made:
    """Write the table, the exports, the preview and the principled material."""
    job, rec, table = steps.job, made.rec, made.table
    assert rec is not None and table is not None
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
    principled, ref = None, made.ref
    if wants_principled(job):
        if made.early is not None:  # its fit sets the process's BLAS threads, as the posterior does: one at a time
            ref = made.early()[0]
        t0 = steps.begin("principled material")
        files, principled = write_principled(job, rec, _name(job, made.working))
        outputs.update(files)
        steps.done("principled", t0)
    return replace(made, outputs=outputs, principled=principled, ref=ref)


def _report(steps: _Steps, made: Made) -> dict[str, Any]:
    """The JSON report (docs/formats.md), the uncertainty and the advice assessed, the report and the HTML page
    written: returns the report."""
    job, rec = steps.job, made.rec
    assert rec is not None
    rep = _report_body(steps, made)
    if made.principled is not None:
        rep["principled"] = made.principled
    _warn(rep, made.loaded.files)
    if made.bounded is not None:
        rep["conservative"] = made.bounded
    sigma_table = None
    if job.assesses:
        t0 = steps.begin("uncertainty")
        sigma_table = _assess(job, rep, made.working, rec, made.opts, steps.begin, steps.done, made.reference,
                              getattr(made.loaded, "capture", None) or {})
        steps.done("uncertainty", t0)
    if not made.checks["all_pass"]:
        rep["implausible_table_written"] = "written with --allow-implausible: " + implausible_message(rec.method,
                                                                                                      made.checks)
    if job.html:
        made.outputs["html"] = str(job.html)
        rep["outputs"]["html"] = str(job.html)
    if job.report:
        made.outputs["report"] = str(job.report)
        rep["outputs"]["report"] = str(job.report)
        summary.write_json(job.report, rep)
    if job.html:
        t0 = steps.begin("html report")
        _write_html(job, rep, made.working, rec, made.table, made.others, made.choice, sigma_table, made.spheres,
                    steps.workers.drawer)
        rep["timings_s"]["html"] = round(time.perf_counter() - t0, 4)
        steps.done("html", t0)
    return rep


def _report_body(steps: _Steps, made: Made) -> dict[str, Any]:
    """The JSON report's body (docs/formats.md)."""
    job, loaded, scene = steps.job, made.loaded, made.scene
    return summary.build_report(
        rec=made.rec, choice=made.choice, working=made.working, table=made.table, checks=made.checks,
        inputs={"files": loaded.files, "quantities": loaded.quantities, "notes": loaded.notes,
                "columns": job.columns, "scene": job.scene,
                **({"scene_ranges_deg": {"theta_i": scene.theta_i_deg, "theta_o": scene.theta_o_deg},
                    **({"scene_view": scene.view} if scene.view else {})} if scene is not None else {})},
        colour=made.colour,
        table_info={"cells": 3 * merltable.N_CELLS,
                    "values": "cell averages" if job.supersample else getattr(made.rec, "table_values", "bin centres")
                    + ("; " + sharprows.DESCRIPTION if made.energy else ""),
                    **({"sharp_rows": made.energy} if made.energy else {}),
                    "supersample": (list(job.supersample) if isinstance(job.supersample, tuple)
                                    else job.supersample),
                    "bin_centres": "theta_h = ((i + 0.5) / 90)^2 * 90 deg, theta_d = j + 0.5 deg, "
                                   "phi_d = k + 0.5 deg"},
        outputs=made.outputs, timings=steps.timings, dropped_blind_spot=loaded.dropped_blind_spot)


def _warn(rep: dict[str, Any], files: list[str]) -> None:
    """Say what the samples cannot support (:func:`reconstruction.report.summary.guard_warnings`): as warnings
    (one line each on the console) and in the report's ``warnings``."""
    said = summary.guard_warnings(rep["coverage"], rep.get("cross_validation"), ", ".join(files), rep.get("method"),
                                  rep.get("parameters"))
    for msg in said:
        warnings.warn(msg, UserWarning, stacklevel=2)
    if said:
        rep["warnings"] = said


def _early_reference(s: Slice, bounds: bool) -> tuple[Any, Array | None]:
    """(the built-in analytic family's posterior of the samples ``s`` (sorted), with ``bounds`` its upper bound
    table for auto's table (:func:`reconstruction.assess.guard.upper_bound_table`) else None): what the run's
    helper thread computes beside the reconstruction."""
    ref = uncertainty.reference_posterior(s)
    return ref, (guard.upper_bound_table(ref, guard.GUARD_SIGMAS_ANALYTIC) if bounds else None)


def bound_where_unmeasured(rec: Reconstruction, table: Array, working: Slice, opts: Options, ref: Any = None,
                           bound: Array | None = None) -> tuple[Reconstruction, Array, dict[str, Any], Any]:
    """``auto``'s table kept below the reference posterior's upper credible bound where no sample rests
    (:mod:`reconstruction.assess.guard`): the prior's with ``--prior``; without, the built-in analytic family's
    (looser, and only where it takes a large share of the light). Returns (the bounded reconstruction, its
    table, the report's ``conservative`` section, the reference posterior); ``ref``: the analytic family's
    posterior of the samples when computed already, ``bound`` its upper bound table if computed too. The
    benchmarks call this as the pipeline does."""
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
    if others is None or rec.method in others:  # the first time, or a fallback to one of them
        others = _other_methods(working, rec, opts, built)
    htmlreport.draw_sample_figures(drawer, working.sorted(), rec, others,
                        choice.get("held_out_predictions", {}).get(rec.method), job.blind_spot_deg or 4.0)
    return others


def _write_html(job: Job, rep: dict[str, Any], working: Slice, rec: Reconstruction, table: Array,
                others: dict[str, Reconstruction], choice: dict[str, Any], sigma: NDArray[np.float32] | None = None,
                spheres: Callable[[], Any] | None = None, drawer: Any = None) -> None:
    """The HTML report of ``job``: ``others``, every other registered method built on the same samples;
    ``spheres``: the sphere renders under way (:func:`reconstruction.report.spheres.sphere_images`); ``drawer``:
    the run's :class:`~reconstruction.report.figures.Drawer`, the sample figures sent."""
    htmlreport.write_html(job.html, report=rep, working=working.sorted(), rec=rec, table=table, alternatives=others,
                          held_out=choice.get("held_out_predictions", {}).get(rec.method), title=_name(job, working),
                          sigma=sigma, spheres=spheres, drawer=drawer)
