"""Capture plans: generators of :mod:`acquisition.plans.messages` that the engine runs.

A capture is :func:`capture`: the calibration (:func:`calibrate`: the dark level and the white reference, or
the calibration of the slice being resumed), the points (:func:`measure`, point by point with :func:`point`),
adaptive refinement (:func:`adaptive`, a plan that is sent the readings it asked for and asks for more where
the slice changes fast) and the final dark reading (:func:`final_dark`). Each is a few lines, and a new
procedure is a new plan, not a change to the engine: see ``examples/reference_every_n.py`` (re-read the white
reference every N points).

``gonio-capture --check`` runs :func:`measure`, the very plan of the capture's points, against a dry-run bench
(:mod:`acquisition.run.dryrun`).
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Generator, Sequence
from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np

from acquisition.calibration import Calibration, Reading
from acquisition.config import BenchConfig
from acquisition.errors import DeviceError, SampleChanged
from acquisition.plans.geometry import Geometry, Point, point_key
from acquisition.plans.messages import (
    Announce,
    Calibrate,
    Checkpoint,
    Convert,
    Dark,
    Move,
    Msg,
    Now,
    Read,
    ReadAt,
    RestoreSetting,
    Save,
    SelectSample,
    Settle,
    Tally,
    UseReference,
    Wait,
    Where,
)
from acquisition.plans.ordering import TWO_OPT_MAX_EVALUATIONS, order_points, path_time
from acquisition.plans.reference import check_reference
from acquisition.plans.refine import refine_points
from reconstruction.schema.bench import AdaptiveTable

log = logging.getLogger("acquisition.plans")

__all__ = ["PlanGen", "PointsPlan", "PlanSpec", "RoundEstimate", "Sample", "point", "measure", "measure_points",
           "white_reference", "rereference", "calibrate", "adaptive", "final_dark", "CaptureContext", "capture",
           "check_sample", "last_recorded", "RESUME_CHECK_POINTS", "RESUME_CHECK_SIGMAS", "RESUME_DRIFT_ALLOWANCE"]

#: A resumed capture first measures again this many of the points recorded last (:func:`check_sample`) ...
RESUME_CHECK_POINTS = 2
#: ... and goes on only if each reads as recorded within this many standard deviations (of the mean, the larger of
#: the two, each side) plus RESUME_DRIFT_ALLOWANCE of the value (the source and detector drifting between runs).
RESUME_CHECK_SIGMAS = 5.0
RESUME_DRIFT_ALLOWANCE = 0.05

#: A plan: yields messages, is sent their replies, returns its result.
PlanGen = Generator[Msg, Any, Any]
#: A measured sample as plans see it: (theta_i, theta_o, mean f_r over channels, mean std), degrees and 1/sr.
Sample = tuple[float, float, float, float]


class PlanSpec(Protocol):
    """What the capture plans need of a plan (:class:`acquisition.plans.plan.Plan` is one): its repeats, order,
    adaptive refinement and final dark. A protocol, so that the plans and the dry run do not import the plan module
    (whose ``Plan.estimate`` asks the dry run)."""

    repeats: int
    order: str
    dark_at_end: bool
    adaptive: AdaptiveTable | None

    def check(self, geom: Geometry) -> Any: ...


def point(theta_i_deg: float, theta_o_deg: float, repeats: int) -> PlanGen:
    """Measure one point: move (a move is also a safe place to stop), settle, read, save. Returns the saved
    :data:`Sample`."""
    yield Move(theta_i_deg, theta_o_deg)
    yield Settle()
    reading, ranged = yield Read(repeats, point=(theta_i_deg, theta_o_deg))
    return (yield Save(theta_i_deg, theta_o_deg, reading, ranged, repeats))


def measure(points: Sequence[Point], geometry: Geometry, repeats: int,
            done: dict[tuple[float, float], Sample] | None, order: str = "optimized",
            max_evaluations: int = TWO_OPT_MAX_EVALUATIONS) -> PlanGen:
    """Measure the points not yet in ``done`` (keys :func:`~acquisition.plans.geometry.point_key`), ordered for short
    arm travel from where the arms are (``order = "optimized"``); every sample is added to ``done`` (None: nothing
    was measured before and nothing needs the samples, as in an estimate)."""
    todo = [p for p in points if point_key(p) not in done] if done else list(points)
    n_done = len(done) if done else 0
    yield Announce(n_done + len(todo), n_done)
    if not todo:
        return
    start = yield Where()
    if order == "optimized":
        todo = order_points(todo, geometry, start=start, max_evaluations=max_evaluations)
    log.info("%d point(s) to measure; estimated motion %.2f s", len(todo), path_time(todo, geometry, start))
    settle = Settle()
    for ti, to in todo:  # point(ti, to, repeats), inlined: a dry run of 20,000 points stays well under a second
        yield Move(ti, to)
        yield settle
        reading, ranged = yield Read(repeats, point=(ti, to))
        sample = yield Save(ti, to, reading, ranged, repeats)
        if done is not None:
            done[point_key((ti, to))] = sample


def white_reference(cfg: BenchConfig, by_hand: list[bool] | None = None, gain_ratios: bool = False) -> PlanGen:
    """Read the white reference at the reference geometry (the reference in front of the detector meanwhile);
    ``gain_ratios``: then at every other gain as well (auto-ranging over gains). Returns (reading, its Ranged
    record or None, {nominal gain: (raw reading, raw dark)} of the gain ratios or None); ``by_hand`` gets whether
    the operator mounted it (no changer)."""
    c = cfg.calibration
    log.info("measuring the white reference at (%g, %g) (%d repeats)", c.reference_theta_i_deg,
             c.reference_theta_o_deg, c.reference_repeats)
    asked = yield SelectSample("REF")
    if by_hand is not None:
        by_hand.append(bool(asked))
    at_gains = None
    try:
        yield Move(c.reference_theta_i_deg, c.reference_theta_o_deg, checkpoint=False)
        yield Settle()
        ref, ranged = yield Read(c.reference_repeats, "white reference", rung=0)
        if gain_ratios:
            at_gains = yield from _reference_at_gains(cfg, ranged)
    finally:
        yield SelectSample("TARGET")
    return ref, ranged, at_gains


def _reference_at_gains(cfg: BenchConfig, ranged: Any) -> PlanGen:
    """The white reference at every gain other than the one it was ranged to, with the dark there (every gain's
    dark is the calibration's): {nominal gain: (raw reading, raw dark)}, for the gain ratios. Not auto-ranged (a
    dry run: ``ranged`` None): the same readings, for their time, and None."""
    gains = sorted(cfg.detector.gains or (), reverse=True)
    if ranged is None or ranged.gain is None:
        for k, g in enumerate(gains[1:], start=1):
            yield ReadAt(cfg.calibration.reference_repeats, k, f"white reference at gain {g:g}")
        return None
    out: dict[float, tuple[Reading, Reading]] = {}
    for k, g in enumerate(gains):
        dark = yield Dark(cfg.detector.dark_repeats, f"dark reading at gain {g:g}", setting=k)
        if abs(g - ranged.gain) <= 1e-9 * g:
            out[float(g)] = (ranged.raw, dark)
            continue
        rd, _ = yield ReadAt(cfg.calibration.reference_repeats, k, f"white reference at gain {g:g}")
        out[float(g)] = (rd, dark)
    return out


def warm_up(cfg: BenchConfig, dark: Reading) -> PlanGen:
    """The warm-up check before the calibration: the white reference read every ``warmup_interval_s`` until its
    last ``warmup_readings`` readings (above the dark) agree within ``warmup_max_drift``; a DeviceError that says
    so after ``warmup_timeout_s`` of bench time."""
    from acquisition.calibration import drift_of

    c = cfg.calibration
    k = max(int(c.warmup_readings), 2)
    log.info("warm-up check: the white reference every %g s until %d readings in a row agree within %g %%",
             c.warmup_interval_s, k, 100 * c.warmup_max_drift)
    nets: list[float] = []
    t0 = yield Now()
    yield SelectSample("REF")
    try:
        yield Move(c.reference_theta_i_deg, c.reference_theta_o_deg, checkpoint=False)
        yield Settle()
        while True:
            rd, _ = yield Read(c.reference_repeats, "warm-up reading of the white reference")
            nets.append(float(np.max(rd.mean - dark.mean)))
            t = (yield Now()) - t0
            if len(nets) >= k and drift_of(nets[-k:]) <= c.warmup_max_drift:
                log.info("warm-up check: the source is steady (%d readings within %.3g %%) after %.0f s", k,
                         100 * drift_of(nets[-k:]), t)
                return
            if t + c.warmup_interval_s > c.warmup_timeout_s:
                drift = drift_of(nets[-k:]) if len(nets) >= 2 else float("nan")
                raise DeviceError(
                    f"the source has not warmed up: its white-reference reading still drifts {100 * drift:.3g} % "
                    f"over the last {min(k, len(nets))} readings ({c.warmup_interval_s:g} s apart; the bound is "
                    f"[calibration].warmup_max_drift = {100 * c.warmup_max_drift:g} %) after {t:.0f} s "
                    f"(warmup_timeout_s = {c.warmup_timeout_s:g}); let the lamp warm up longer (a halogen lamp "
                    "takes 10-20 min, an LED a few) and check its supply, then run the capture again")
            yield Wait(c.warmup_interval_s)
    finally:
        yield SelectSample("TARGET")


def rereference(cfg: BenchConfig) -> PlanGen:
    """Read the white reference again and convert with it from now on (relative calibration; the dark level and
    the slice's metadata keep the first reading, the log records each new one)."""
    ref, _, _ = yield from white_reference(cfg)
    yield UseReference(ref)


def footprint_of(cfg: BenchConfig) -> tuple[float, float, float] | None:
    """The calibration's footprint: (beam, sample diameter in mm, the smallest fraction corrected), or None."""
    from acquisition.optics import MIN_CORRECTABLE_FRACTION

    b = cfg.bench
    if b.beam_diameter_mm is None or b.sample_diameter_mm is None:
        return None
    return (b.beam_diameter_mm, b.sample_diameter_mm, MIN_CORRECTABLE_FRACTION)


def calibrate(cfg: BenchConfig, rho_ref: np.ndarray) -> PlanGen:
    """The dark level (auto-ranged over gains: at every gain), then (relative calibration) the white reference;
    tells the engine to convert with the result. Returns the :class:`Calibration`."""
    c = cfg.calibration
    log.info("measuring the dark level (%d repeats, source off)", cfg.detector.dark_repeats)
    dark = yield Dark(cfg.detector.dark_repeats, "dark reading", calibration=True)
    if c.mode == "relative" and c.warmup_readings:
        yield from warm_up(cfg, dark)
    d = cfg.detector
    if d.auto_range and d.gains:  # a dark at every other gain now, with the source off anyway: what auto-ranging
        for k, g in enumerate(sorted(d.gains, reverse=True)[1:], start=1):  # converts with, known to the estimate
            yield Dark(d.dark_repeats, f"dark reading at gain {g:g}", setting=k)
    t_ref_read = cfg.detector.integration_time_s
    factors: tuple[dict[float, float] | None, tuple[float, ...]] = (None, ())
    if c.mode == "relative":
        by_hand: list[bool] = []
        ratios = bool(d.auto_range and d.gains and len(d.gains) > 1 and c.gain_ratios == "measured")
        ref, ranged, at_gains = yield from white_reference(cfg, by_hand, gain_ratios=ratios)
        if at_gains:
            factors = _gain_factors(at_gains, ranged, cfg)
        if ranged is not None:
            t_ref_read = ranged.integration_time_s
            if ranged.ranged:
                log.info("white reference: auto-ranged to t_int = %g s%s", t_ref_read,
                         "" if ranged.gain is None else f", gain {ranged.gain:g}")
                if ranged.dark is not None:  # the dark it was converted with: its uncertainty is the reference's
                    d = ranged.dark
                    ref = Reading(ref.mean, np.sqrt(ref.std ** 2 + ref.n * d.std_of_mean ** 2), ref.n,
                                  ref.saturated, ref.monitor)
        cal = Calibration("relative", dark, ref, rho_ref, c.reference_theta_o_deg, footprint=footprint_of(cfg),
                          reference_theta_i_deg=c.reference_theta_i_deg, gain_factors=factors[0],
                          gain_factors_measured=factors[1], monitor=cfg.detector.monitor)
        try:
            cal.scale(c.reference_theta_o_deg)  # raises if the reference reads no signal
            cal.monitor_factor(ref)  # ... or, for ratio readings, its monitor none
        except ValueError as e:
            raise DeviceError(f"white reference at ({c.reference_theta_i_deg:g}, {c.reference_theta_o_deg:g}): "
                              f"{e} (reference {ref.mean.tolist()[:4]}, dark {dark.mean.tolist()[:4]} counts)"
                              ) from None
        yield from check_reference(ref, dark, c.reference_repeats, rho_ref, any(by_hand))  # named before the sweep
    else:
        assert c.source_power is not None and c.detector_solid_angle_sr is not None
        # source_power is counts at gain 1; readings are converted to the reference setting's gain
        gains = cfg.detector.gains
        g_ref = 1.0 if not gains else (max(gains) if cfg.detector.auto_range else min(gains))
        cal = Calibration("absolute", dark, k_counts=c.source_power * c.detector_solid_angle_sr * g_ref,
                          footprint=footprint_of(cfg))
    log.info("dark %s counts; %s", np.round(dark.mean, 3).tolist()[:8],
             f"reference {np.round(cal.reference.mean, 3).tolist()[:8]} counts" if cal.reference else
             f"K = {cal.k_counts:g} counts")
    yield Calibrate(cal, t_ref_read if c.mode == "relative" else None)
    return cal


def _gain_factors(at_gains: dict[float, tuple[Reading, Reading]], ranged: Any, cfg: BenchConfig
                  ) -> tuple[dict[float, float], tuple[float, ...]]:
    """The gain factors from the white reference at every gain (:func:`measure_gain_factors`), logged."""
    from acquisition.calibration import measure_gain_factors

    sat = float(cfg.detector.saturation) if cfg.detector.saturation is not None else math.inf  # (the device's)
    factors, measured = measure_gain_factors(at_gains, float(ranged.gain), sat)
    nominal = sorted(set(factors) - set(measured) - {float(ranged.gain)}, reverse=True)
    log.info("gain ratios measured on the white reference (real / nominal, relative to gain %g): %s%s",
             ranged.gain, ", ".join(f"{g:g}: {factors[g]:.4f}" for g in measured) or "none",
             f"; nominal ratio kept at {', '.join(f'{g:g}' for g in nominal)} (the reference saturates there or "
             "reads too little)" if nominal else "")
    return factors, measured


def adaptive(ctx: CaptureContext, t_start: float) -> PlanGen:
    """Adaptive refinement: rounds of midpoints where the measured slice changes fast
    (:func:`~acquisition.plans.refine.refine_points`), measured by the context's points plan and sent back through
    ``ctx.done``, until it converges, the point limit or the time budget (bench seconds since ``t_start``) is
    reached."""
    a, geometry, done = ctx.plan.adaptive, ctx.geometry, ctx.done
    assert a is not None
    known = {point_key(p) for p in ctx.measurable}
    t_est = 0.0
    for rnd in range(1, a.max_rounds + 1):
        samples: dict[float, list[tuple[float, float, float]]] = {}
        for k in known:
            ti, to, v, s = done[k]
            samples.setdefault(ti, []).append((to, v, s))
        new = refine_points(samples, geometry, a.tolerance, a.min_step_deg, known)
        if a.max_points and len(known) + len(new) > a.max_points:
            new = new[: max(a.max_points - len(known), 0)]
            log.info("adaptive: point limit %d reached", a.max_points)
        if not new:
            log.info("adaptive: converged after %d round(s) (tolerance %g)", rnd - 1, a.tolerance)
            break
        if a.time_budget_s and (yield Now()) - t_start > a.time_budget_s:
            log.info("adaptive: time budget %g s used up before round %d", a.time_budget_s, rnd)
            break
        if ctx.estimate_points is not None:  # the round's time, estimated as it is planned
            t_round = ctx.estimate_points(ctx, new, (yield Where()), ctx.cfg.detector.integration_time_s)
            t_est += t_round
            yield Tally("estimate_refinement_s", t_est)
            log.info("adaptive round %d: %d new point(s), estimated %.2f s", rnd, len(new), t_round)
        else:
            log.info("adaptive round %d: %d new point(s)", rnd, len(new))
        yield from ctx.points_plan(ctx, new)
        known |= {point_key(p) for p in new}
        yield Tally("adaptive_rounds", rnd)
        if a.max_points and len(known) >= a.max_points:
            break


def last_recorded(points: Sequence[Point], k: int = RESUME_CHECK_POINTS) -> list[Point]:
    """The last ``k`` distinct points of ``points`` (a slice's rows, in the order they were recorded), in that
    order."""
    out: list[Point] = []
    seen: set[tuple[float, float]] = set()
    for p in reversed(points):
        key = point_key(p)
        if key not in seen:
            seen.add(key)
            out.append((float(p[0]), float(p[1])))
            if len(out) == k:
                break
    return out[::-1]


def check_sample(ctx: CaptureContext) -> PlanGen:
    """A resume's first step: measure ``ctx.recheck`` (the points recorded last) again and compare each with its
    sample in ``ctx.done``: they agree within :data:`RESUME_CHECK_SIGMAS` standard deviations plus
    :data:`RESUME_DRIFT_ALLOWANCE` of the value, or another sample is on the bench (swapped, moved, turned: the
    settings' fingerprint cannot see that) and :class:`SampleChanged` stops the capture before anything new is
    measured, unless ``ctx.accept_changed_sample`` (``--resume --force``: logged). Tallies ``sample_check``
    (the points, both readings, the verdict) for the run record."""
    rows = []
    for ti, to in ctx.recheck:
        old = ctx.done.get(point_key((ti, to)))
        if old is None:
            continue
        yield Move(ti, to)
        yield Settle()
        reading, _ = yield Read(ctx.plan.repeats, point=(ti, to))
        _, _, v, sd = yield Convert(ti, to, reading)
        _, _, v0, sd0 = old
        tol = RESUME_CHECK_SIGMAS * math.sqrt(2.0) * max(sd, sd0) + RESUME_DRIFT_ALLOWANCE * max(abs(v), abs(v0))
        rows.append({"theta_i_deg": ti, "theta_o_deg": to, "recorded": v0, "recorded_std": sd0, "now": v,
                     "now_std": sd, "agree": bool(abs(v - v0) <= tol)})
    if not rows:
        return
    agree = all(r["agree"] for r in rows)
    yield Tally("sample_check", {"points": rows, "agree": agree, "forced": not agree and ctx.accept_changed_sample,
                                 "sigmas": RESUME_CHECK_SIGMAS, "drift_allowance": RESUME_DRIFT_ALLOWANCE})
    text = "; ".join(f"at ({r['theta_i_deg']:g}, {r['theta_o_deg']:g}) it read {r['recorded']:.4g} +- "
                     f"{r['recorded_std']:.2g} 1/sr then and {r['now']:.4g} +- {r['now_std']:.2g} 1/sr now"
                     for r in rows)
    if agree:
        log.info("resume: the sample reads as recorded (%s)", text)
        return
    where = f"{text} (more than {RESUME_CHECK_SIGMAS:g} sigma + {100 * RESUME_DRIFT_ALLOWANCE:g} % apart)"
    if ctx.accept_changed_sample:
        log.warning("resume: the sample does not read as recorded: %s; going on as --force asks (recorded in the "
                    "run record)", where)
        return
    raise SampleChanged(f"the sample on the bench does not read as the one recorded: {where}")


def final_dark(cfg: BenchConfig, calibration: Calibration) -> PlanGen:
    """The dark level again at the end: its drift since the calibration is logged and recorded."""
    yield Checkpoint()
    d_end: Reading = yield Dark(cfg.detector.dark_repeats, "dark reading")
    yield Checkpoint()  # a signal during the final dark: stopped; a resume measures it again
    drift = d_end.mean - calibration.dark.mean
    yield Tally("dark_drift", [float(x) for x in drift])
    noise = calibration.dark.std_of_mean + d_end.std_of_mean
    lvl = "warning" if np.any(np.abs(drift) > 3 * np.maximum(noise, 1e-9)) else "info"
    getattr(log, lvl)("dark level drift over the capture: %s counts (start %s)", np.round(drift, 3).tolist(),
                      np.round(calibration.dark.mean, 3).tolist())


def measure_points(ctx: CaptureContext, points: Sequence[Point]) -> PlanGen:
    """The default points plan of a capture: :func:`measure` with the capture's plan settings."""
    yield from measure(points, ctx.geometry, ctx.plan.repeats, ctx.done, ctx.plan.order)


#: A points plan: measures ``points`` within a capture (the samples go to ``ctx.done``).
PointsPlan = Callable[["CaptureContext", Sequence[Point]], PlanGen]
#: How a round of adaptive refinement is estimated as it is planned: (context, the round's points, where the arms
#: are, the integration time in s) -> bench seconds (:func:`acquisition.run.dryrun.estimate_points`).
RoundEstimate = Callable[["CaptureContext", Sequence[Point], Point, float], float]


@dataclass
class CaptureContext:
    """What :func:`capture` needs: the bench file, the plan, the geometry, the measurable points, the samples
    already in the slice (a resume) and its calibration (None: measure one), the white reference's rho per
    channel, the bench time of this capture's earlier runs (s), the plan that measures points
    (:func:`measure_points`, or a procedure of one's own, e.g. ``examples/reference_every_n.py``), and how a round of
    adaptive refinement is estimated as it is planned (the capture gives :func:`acquisition.run.dryrun.estimate_points`:
    the caller asks the dry run, the plans do not; None: the rounds are not estimated). A resume measures
    ``recheck`` again first (:func:`check_sample`; ``accept_changed_sample``: go on if they disagree)."""

    cfg: BenchConfig
    plan: PlanSpec
    geometry: Geometry
    measurable: list[Point]
    done: dict[tuple[float, float], Sample] = field(default_factory=dict)
    calibration: Calibration | None = None
    rho_ref: Any = None
    previous_bench_time_s: float = 0.0
    points_plan: PointsPlan = measure_points
    estimate_points: RoundEstimate | None = None
    recheck: list[Point] = field(default_factory=list)
    accept_changed_sample: bool = False


def capture(ctx: CaptureContext) -> PlanGen:
    """The whole capture: calibration (a resume: the slice's, and the last points measured again), the points,
    adaptive refinement, the final dark reading."""
    t0 = yield Now()
    if ctx.calibration is not None:  # a resume: the slice's own calibration, and the same sample?
        yield SelectSample("TARGET")
        yield Calibrate(ctx.calibration)
        cal = ctx.calibration
        yield from check_sample(ctx)
    else:
        cal = yield from calibrate(ctx.cfg, ctx.rho_ref)
    yield from ctx.points_plan(ctx, ctx.measurable)
    if ctx.plan.adaptive is not None:
        yield from adaptive(ctx, t0 - ctx.previous_bench_time_s)  # the budget counts every run of this capture
    yield RestoreSetting()
    if ctx.plan.dark_at_end:
        yield from final_dark(ctx.cfg, cal)
