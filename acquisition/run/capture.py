"""A capture as a whole: :class:`RunEngine` runs one capture of a plan on a bench into ``DIR/slice.csv``:
checkpointed, resumable, interrupt-safe.

The slice file is the checkpoint. Its metadata (written once, when the file is created) holds the plan, its
fingerprint, the dark level and the white-reference reading; every sample is appended (and fsynced) the moment
it is measured. A resume reads the file, checks that it continues the same experiment (:mod:`acquisition.run.outdir`),
reuses the stored calibration and measures only the missing points, so no sample is lost and none is taken
twice. ``DIR/capture.json`` is the run record (:mod:`acquisition.run.record`), ``DIR/capture.log`` the log,
``DIR/simulator.log`` the simulator's log on a simulated bench.

What is measured, and in which order, is the capture plan (:func:`acquisition.plans.capture`), run by the engine
(:class:`acquisition.run.engine.Engine`) against the bench's devices. Here: the output folder is locked
(``DIR/capture.lock``, :mod:`acquisition.run.lock`) and checked writable before anything moves; the bench is opened
(a resumed run starts the simulator with ``--attempt N`` so its noise and faults continue their random streams);
Ctrl-C and SIGTERM become a flag that the motion wait loops and the plan's checkpoints check, and the arms are
then parked and torque switched off (a second signal aborts the parking; no signal ends in a traceback, and one
that arrives during the final dark reading or the parking still gives the signal's exit status). A hardware
fault or a communication failure stops the same way, without parking when an axis reports a fault; a full disk
stops it with one line saying so. How a capture ended is a :class:`~acquisition.run.record.Stop`; the exit status
is :func:`acquisition.run.record.exit_status`.
"""

from __future__ import annotations

import json
import logging
import math
import signal
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

from acquisition.calibration import Calibration, Reading, gain_factors_of, reference_rho
from acquisition.errors import (
    CaptureInterrupted,
    CommError,
    ConfigError,
    DeviceError,
    HardwareError,
    PlanError,
    PortError,
    SampleChanged,
)
from acquisition.optics import footprint_warning
from acquisition.plans.generators import (
    CaptureContext,
    PointsPlan,
    Sample,
    capture,
    footprint_of,
    last_recorded,
    measure_points,
)
from acquisition.plans.geometry import point_key
from acquisition.plans.plan import Plan
from acquisition.run.dryrun import estimate, estimate_points
from acquisition.run.engine import Engine
from acquisition.run.fingerprint import describe_differences, fingerprint, settings
from acquisition.run.interrupts import SignalGuard
from acquisition.run.lock import OutLock
from acquisition.run.outdir import (
    LOG_NAME,
    SIM_LOG_NAME,
    SLICE_NAME,
    check_resume,
    check_writable,
    make_out_dir,
)
from acquisition.run.progress import PROGRESS_NAME, ProgressFile
from acquisition.run.record import (
    SIDECAR_NAME,
    AutoRangeRecord,
    CaptureResult,
    RunRecord,
    Stop,
    exit_status,
)
from acquisition.run.sliceout import SliceOutput
from reconstruction.atomic import is_no_space
from reconstruction.core.slicedata import Slice

log = logging.getLogger("acquisition.engine")

__all__ = ["RunEngine"]


class _LogFile(logging.FileHandler):
    """``capture.log``: a write that fails (a full disk) never prints logging's "--- Logging error ---" traceback;
    the log stops growing and the capture reports its own write failures in one line."""

    failed = False

    def handleError(self, record: logging.LogRecord) -> None:
        self.failed = True

    def flush(self) -> None:
        try:
            super().flush()
        except OSError:
            self.failed = True

    def close(self) -> None:
        try:
            super().close()
        except OSError:
            pass


class _Bar:
    """The capture's progress bar (tqdm on stderr; by default only on a terminal)."""

    def __init__(self, progress: bool | None, watch: ProgressFile | None = None) -> None:
        self.enabled = sys.stderr.isatty() if progress is None else bool(progress)
        self.pbar: Any = None
        self.watch = watch  # progress.json of the live view

    def announce(self, total: int, done: int) -> None:
        if self.watch is not None:
            self.watch.announce(total, done)
        if self.pbar is None:
            from tqdm import tqdm

            self.pbar = tqdm(total=total, initial=done, unit="pt", desc="capture", disable=not self.enabled,
                             dynamic_ncols=True)
        else:
            self.pbar.total = total
            self.pbar.refresh()

    def advance(self) -> None:
        if self.pbar is not None:
            self.pbar.update(1)

    def close(self) -> None:
        if self.pbar is not None:
            self.pbar.close()


class RunEngine:
    """Runs one capture of ``plan`` on ``bench`` into ``out``; see the module docstring."""

    def __init__(self, bench: Any, plan: Plan, out: str | Path, resume: bool = False, progress: bool | None = None,
                 handle_signals: bool = True, points_plan: PointsPlan | None = None, force: bool = False,
                 live: bool = False) -> None:
        self.points_plan = points_plan or measure_points
        self.live = live  # write progress.json for the live view (acquisition.live)
        self.force = force  # a resume goes on with another sample on the bench (recorded in capture.json)
        self.bench = bench
        self.cfg = bench.cfg
        self.plan = plan
        self.out = Path(out)
        self.resume = resume
        self.progress = progress
        self.handle_signals = handle_signals
        self.slice_path = self.out / SLICE_NAME
        self.sidecar_path = self.out / SIDECAR_NAME
        self.result = CaptureResult(str(self.out), str(self.slice_path))
        self.record = RunRecord(self.sidecar_path)
        self.fingerprint: dict[str, Any] = {}
        self.settings: dict[str, Any] = {}
        self._guard = SignalGuard(False)
        self._run_started = False
        self._before_motion = False  # the run stopped before the bench was open: nothing to resume or park
        self._io_fault = False  # an output file could not be written (a full disk)
        self._unopened = False  # a port of the bench could not be opened: nothing moved, nothing to resume
        self._found: set[str] = set()  # what the output folder held before this run
        self._engine: Engine | None = None
        self._measurable: list[Any] = []

    def plan_points(self) -> list[Any]:
        """The plan's measurable points (theta_i, theta_o) in degrees."""
        return self._measurable

    def run(self) -> CaptureResult:
        """Validate, lock the output folder, check it is writable, then capture. Raises PlanError / ConfigError
        before any motion (:class:`~acquisition.run.lock.OutDirLocked` when another capture holds the folder); every
        later failure is returned as a result with ``status``, ``stop`` and ``exit_code`` after the arms were
        made safe."""

        t_wall0 = time.monotonic()
        geom = self.bench.geometry
        chk = self.plan.validate(geom)  # before anything moves or opens
        self.result.points_planned = len(chk.measurable)
        self._measurable = list(chk.measurable)
        self.result.unmeasurable = [[ti, to, why] for ti, to, why in chk.unmeasurable]
        self.fingerprint = fingerprint(self.cfg, self.plan.fingerprint())
        self.settings = settings(self.cfg)
        with SignalGuard(self.handle_signals) as guard:  # from here on no signal ends in a traceback
            self._guard = guard
            make_out_dir(self.out)
            self._found = {p.name for p in self.out.iterdir()}
            lock = OutLock(self.out)
            stale = lock.acquire()
            try:
                check_writable(self.out)
                self.record = RunRecord.load(self.sidecar_path)
                res = check_resume(self.cfg, self.plan, self.out, self.resume, self.record, self.fingerprint,
                                   self.settings, self.force, self._measurable, geom)
                est = self._estimate(chk, res.existing)
                self._run_locked(chk, est, res, stale_pid=stale, t_wall0=t_wall0)
            finally:
                if self._unopened:  # while the lock is held: no other capture has started here yet
                    self._forget_unopened_run()
                lock.release()
        return self.result

    def _forget_unopened_run(self) -> None:
        """A run whose bench could not be opened measured nothing and has nothing to resume: the run record and
        log it started are removed (what the folder held before stays; the console said why)."""
        for path in (self.sidecar_path, self.out / LOG_NAME):
            if path.name not in self._found:
                try:
                    path.unlink()
                except OSError:  # pragma: no cover - a folder that turned read-only
                    pass

    def _estimate(self, chk: Any, existing: Slice | None) -> dict[str, float]:
        """The time model's estimate of this run (:func:`acquisition.run.dryrun.estimate`): the whole capture plan on a
        dry-run bench, from the calibration (or the resumed slice's) to the final dark."""
        done = [] if existing is None else list(zip(existing.theta_i_deg, existing.theta_o_deg, strict=True))
        est = estimate(self.plan, self.bench.geometry, self.cfg.detector.integration_time_s, chk.measurable,
                       cfg=self.cfg, points_plan=self.points_plan, done=done, calibrated=existing is not None)
        r = self.result
        r.plan_motion_estimate_s = est["motion_s"]
        r.naive_motion_estimate_s = est["naive_motion_s"]
        r.estimate_s = est["total_s"]
        r.estimate = est
        return est

    def _run_locked(self, chk: Any, est: dict[str, float], res: Any, stale_pid: int | None, t_wall0: float) -> None:
        existing: Slice | None = res.existing
        self.result.samples_total = len(existing) if existing is not None else 0  # kept if the run stops early
        handler = self._attach_log()
        try:
            if stale_pid is not None:
                log.info("took over %s from PID %d, which ended without releasing it (killed?)",
                         self.out / "capture.lock", stale_pid)
            self._log_plan(chk, est)
            res.log_checks(self.slice_path)
            if existing is not None and self.record.status == "complete" and self._all_done(existing, chk.measurable):
                self.result.samples_total = len(existing)
                self.result.estimate_s, self.result.estimate = 0.0, {}  # nothing to do, nothing was done
                self.result.end(Stop.COMPLETE, f"{self.slice_path} is already complete ({len(existing)} samples)")
                log.info(self.result.message)
                return
            try:
                self._start_run_record(existing)
            except OSError as e:  # a full disk before anything moved
                self._before_motion = True
                self._io_failure(e)
                return
            self._capture(existing, chk.measurable)
        finally:
            self.result.wall_s = time.monotonic() - t_wall0
            if self.result.samples_new:
                self.result.wall_per_sample_s = self.result.wall_s / self.result.samples_new
            if res.sample_changes:  # --force accepted another [material]: the run record says so
                self.result.sample_check = {**(self.result.sample_check or {}), "forced": True,
                                            "config_changes": describe_differences(res.sample_changes)}
            if self._run_started:
                self.record.plan_fields["estimate"] = self._estimate_fields()  # with the refinement rounds
                self.record.finish_run(self.result)
            self._guard.drain()  # what the signal handler said comes before the outcome
            self._report()
            logging.getLogger("acquisition").removeHandler(handler)
            handler.close()

    def _attach_log(self) -> logging.Handler:
        h = _LogFile(self.out / LOG_NAME, encoding="utf-8")
        h.setFormatter(logging.Formatter("%(asctime)s %(levelname)s %(name)s: %(message)s"))
        h.setLevel(logging.INFO)
        lg = logging.getLogger("acquisition")
        lg.addHandler(h)
        if lg.level == logging.NOTSET or lg.level > logging.INFO:
            lg.setLevel(logging.INFO)
        return h

    def _log_plan(self, chk: Any, est: dict[str, float]) -> None:
        log.info("capture %s: config %s, plan %s (fingerprint %s), %s", "resumed" if self.resume else "started",
                 self.cfg.path, json.dumps(self.plan.to_meta())[:300], self.plan.fingerprint(),
                 f"{len(chk.measurable)} measurable points")
        for ti, to, why in chk.unmeasurable:
            log.info("not measurable: (%g, %g): %s", ti, to, why)
        log.info("estimated bench time %.2f s: motion %.2f s in plan order (%.2f s in naive order), settle %.2f s, "
                 "detector %.2f s, darks and white reference %.2f s", est["total_s"], est["motion_s"],
                 est["naive_motion_s"], est["settle_s"], est["read_s"], est["calibration_s"])
        warn = footprint_warning(self.cfg, [p[0] for p in chk.measurable])
        if warn:
            log.warning("%s", warn)

    @staticmethod
    def _all_done(existing: Slice, pts: list[Any]) -> bool:
        have = {point_key((a, b)) for a, b in zip(existing.theta_i_deg, existing.theta_o_deg, strict=True)}
        return all(point_key(p) in have for p in pts)

    def _start_run_record(self, existing: Slice | None) -> None:
        r = self.result
        self.record.start_run({
            "config": str(self.cfg.path), "plan": self.plan.to_meta(), "plan_fingerprint": self.plan.fingerprint(),
            "points_planned": r.points_planned, "unmeasurable": r.unmeasurable,
            "estimate": self._estimate_fields(),
        }, resume=existing is not None, samples_before=0 if existing is None else len(existing))
        self._run_started = True
        attempt = len(self.record.runs) - 1
        if attempt and hasattr(self.bench, "sim_args"):  # the simulator's random streams continue, not replay
            self.bench.sim_args = ("--attempt", str(attempt))

    def _estimate_fields(self) -> dict[str, float]:
        """``estimate`` of capture.json: the time model's figures of this run (s): its parts, ``before_refinement_s``
        (what ``--check`` says), ``refinement_s`` (the rounds, estimated as they were planned), ``this_run_s`` (their
        sum), and ``total_s`` = ``previous_runs_s`` (the bench time of this capture's earlier runs) +
        ``this_run_s``, to compare with ``totals.bench_time_s``."""
        r = self.result
        keys = ("motion_s", "naive_motion_s", "settle_s", "read_s", "calibration_s", "park_s")
        d = {k: float(r.estimate[k]) for k in keys if k in r.estimate}
        d["before_refinement_s"] = float(r.estimate.get("total_s", 0.0))
        d["refinement_s"] = float(r.estimate_refinement_s)
        d["this_run_s"] = d["before_refinement_s"] + d["refinement_s"]
        d["previous_runs_s"] = float(sum(run.get("bench_time_s", 0.0) for run in self.record.runs
                                         if "ended_unix" in run))  # the runs before this one
        d["total_s"] = d["previous_runs_s"] + d["this_run_s"]
        return d

    def _auto_range_record(self, existing: Slice | None) -> None:
        """The run record's auto-ranging part: kept from earlier runs of the capture (same reference setting),
        else started afresh."""
        d = self.cfg.detector
        if not d.auto_range:
            return
        rec = self.record.auto_range
        same = rec is not None and math.isclose(float(rec.reference_integration_time_s), d.integration_time_s,
                                                rel_tol=1e-9)
        if existing is None or not same or rec is None:
            if existing is not None:
                log.info("auto-ranging: no record of earlier runs in %s; darks at other settings are measured "
                         "again when needed", self.sidecar_path)
            rec = AutoRangeRecord()
        rec.enabled = True
        rec.reference_integration_time_s = d.integration_time_s
        rec.min_integration_time_s = d.min_integration_time_s
        if rec.darks:
            log.info("auto-ranging: reusing the dark level at %s s from %s", ", ".join(sorted(rec.darks)),
                     self.sidecar_path)
        self.record.auto_range = rec

    def _resumed(self, existing: Slice) -> tuple[Calibration, dict[tuple[float, float], Sample]]:
        """The calibration stored in the slice being resumed, and its samples."""
        c = self.cfg.calibration
        channels = self.bench.detector.channels
        if sorted(existing.channels) != sorted(channels):
            raise PlanError(f"cannot resume: {self.slice_path} has channels {existing.channels[:4]}..., the "
                            f"detector gives {channels[:4]}...")
        m = existing.meta["calibration"]
        cal = Calibration(c.mode, Reading.from_meta(m["dark"]),
                          Reading.from_meta(m["reference_reading"]) if "reference_reading" in m else None,
                          np.asarray(m["rho_ref"]) if "rho_ref" in m else None,
                          float(m.get("reference_theta_o_deg", c.reference_theta_o_deg)), m.get("k_counts"),
                          footprint_of(self.cfg) if "footprint" in m else None,
                          float(m.get("reference_theta_i_deg", c.reference_theta_i_deg)), *gain_factors_of(m),
                          monitor=bool(m.get("monitor_ratio", False)))
        done: dict[tuple[float, float], Sample] = {}
        for ti, to, v, s in zip(existing.theta_i_deg, existing.theta_o_deg, existing.values.mean(axis=1),
                                existing.std.mean(axis=1), strict=True):
            done[point_key((ti, to))] = (float(ti), float(to), float(v), float(s))
        log.info("resuming: %d samples already in %s; calibration reused from its metadata", len(done),
                 self.slice_path)
        return cal, done

    def _capture(self, existing: Slice | None, measurable: list[Any]) -> None:
        r = self.result
        bench = self.bench
        cfg = self.cfg
        opened_here = False
        hardware_fault = False
        watch = ProgressFile(self.out / PROGRESS_NAME, r.estimate_s, r.points_planned) if self.live else None
        sink = SliceOutput(self, resume=existing is not None, watch=watch)
        bar = _Bar(self.progress, watch)
        try:
            try:
                self._guard.check()  # a signal during the start-up: stop before anything opens
                if not bench.is_open:
                    if bench.cfg.bench.transport == "simulated":
                        bench.simulator_log = self.out / SIM_LOG_NAME
                    try:
                        bench.open()
                    except (PortError, DeviceError) as e:  # a port or a library (no VISA): nothing started
                        self._unopened = self._before_motion = not isinstance(e, HardwareError)
                        raise
                    opened_here = True
                bench.motion.cancel = self._guard.check
                r.bench_clock = "controller" if bench.has_clock else "wall"
                t0 = bench.now()
                try:
                    self._auto_range_record(existing)
                    cal, done = self._resumed(existing) if existing is not None else (None, {})
                    d = cfg.detector
                    engine = self._engine = Engine(
                        bench.devices(), settle_s=cfg.motion.settle_s, retries=cfg.motion.retries, result=r,
                        sink=sink, record=self.record, guard=self._guard, bar=bar,
                        auto_range=(d.integration_time_s, d.min_integration_time_s, d.dark_repeats)
                        if d.auto_range else None, auto_range_hint=not d.auto_range, samples_total=len(done),
                        gains=d.gains)
                    engine.t_last = t0
                    if engine.ranger is not None and self.record.auto_range is not None:
                        self.record.auto_range.prune(set(done), point_key)
                        engine.update_range_counts()
                        if existing is not None and cal is not None:  # the old neighbours predict settings too
                            engine.seed_ranger(cal, existing)
                    c = cfg.calibration
                    rho = reference_rho(c.reference_reflectance, c.reference_spectrum, bench.detector.wavelengths_nm,
                                        d.band_weights)
                    recheck = [] if existing is None else last_recorded(list(zip(
                        existing.theta_i_deg, existing.theta_o_deg, strict=True)))
                    engine.run(capture(CaptureContext(cfg, self.plan, bench.geometry, measurable, done, cal, rho,
                                                      self.record.previous_bench_time(), self.points_plan,
                                                      estimate_points, recheck, self.force)))
                finally:
                    try:
                        r.bench_time_s = bench.now() - t0
                    except Exception:  # the link may be gone after a failure: keep the last known time
                        if self._engine is not None and self._engine.t_last is not None:
                            r.bench_time_s = self._engine.t_last - t0
                r.end(Stop.COMPLETE, f"captured {r.samples_new} new sample(s); {r.samples_total} in {self.slice_path}")
            except CaptureInterrupted as e:
                r.end(Stop.INTERRUPTED, f"capture {e}", e.signum or signal.SIGINT)
            except KeyboardInterrupt:
                r.end(Stop.INTERRUPTED, "capture interrupted", signal.SIGINT)
            except HardwareError as e:
                hardware_fault = True
                r.end(Stop.HARDWARE_FAULT, f"hardware fault: {e}")
            except (CommError, DeviceError) as e:
                r.end(Stop.BENCH_FAILURE, f"bench failure: {e}")
            except ConfigError as e:  # the simulator refused its sections of the config, when it was started
                self._before_motion = True
                r.end(Stop.CONFIG_REFUSED, f"{e}; nothing was moved")
            except PlanError as e:
                r.end(Stop.PLAN_ERROR, str(e))
            except SampleChanged as e:
                r.end(Stop.SAMPLE_CHANGED, f"cannot resume: {e}. If the sample was changed on purpose, go on with: "
                                           f"{self.resume_command()} --force (recorded in {self.sidecar_path}); "
                                           "otherwise mount the recorded sample as it was, and resume again")
            except OSError as e:  # the slice, the run record or the log cannot be written (a full disk)
                self._io_failure(e)
            except Exception as e:  # a bug or an unforeseen device reply: still stop safely and stay resumable
                log.exception("unexpected error")
                r.end(Stop.UNEXPECTED, f"unexpected error: {e!r} (details in {self.out / LOG_NAME})")
        finally:
            bar.close()
            sink.close()
            if watch is not None:
                watch.finish(r.status, r.message)
            if r.status != "complete" and not hardware_fault:
                self._restore_integration_time()
            self._make_safe(opened_here, hardware_fault)
            if self._guard.signum is not None and r.status == "complete":
                # everything was measured, but the signal arrived while stopping: say so in the exit status
                name = signal.Signals(self._guard.signum).name
                r.signum = self._guard.signum
                r.exit_code = exit_status(Stop.INTERRUPTED, self._guard.signum)
                r.message += f"; {name} arrived while parking the arms: check that they are parked"

    def _make_safe(self, opened_here: bool, hardware_fault: bool) -> None:
        """Park (unless an axis reports a fault) and switch torque off; a bench the caller opened stays open."""
        bench, r = self.bench, self.result
        try:
            if bench.is_open:
                if bench.motion is not None:
                    bench.motion.cancel = self._guard.check_abort  # only a second signal stops the parking
                if opened_here or r.status != "complete":
                    bench.shutdown(park=not hardware_fault)  # park, torque off
                else:  # the caller's bench stays ready: park only
                    try:
                        bench.park(check_cancel=True)
                    except BaseException as e:  # noqa: BLE001 - make safe whatever went wrong
                        log.error("parking failed: %s", e)
                        bench.shutdown(park=False)
                if bench.motion is not None:
                    bench.motion.cancel = lambda: None
        finally:
            if opened_here:
                bench.close()

    def _restore_integration_time(self) -> None:
        """Best effort after a failure: leave the detector at the configured integration time."""
        ranger = self._engine.ranger if self._engine is not None else None
        link = self.bench.link
        if ranger is None or not self.bench.is_open or link is None or link.dead:
            return
        try:
            ranger.restore()
        except Exception as e:  # noqa: BLE001 - the bench is being made safe; the next connect sets INT again
            log.warning("could not restore the integration time: %s", e)

    def _io_failure(self, e: OSError) -> None:
        """The run stops because an output file cannot be written; one line says which and why."""
        self._io_fault = True
        where = e.filename or "an output file"
        if is_no_space(e):
            msg = f"the disk is full (or a file size limit was reached): cannot write {where} ({e.strerror or e})"
        else:
            msg = f"cannot write {where} ({e.strerror or e})"
        self.result.end(Stop.IO_FAULT, msg)

    def _report(self) -> None:
        r = self.result
        if r.status == "complete":
            log.info("%s; bench time %.3f s (%s clock): motion %.3f s, settle %.3f s, detector %.3f s; wall %.3f s",
                     r.message, r.bench_time_s, r.bench_clock, r.motion_s, r.settle_s, r.read_s, r.wall_s)
            return
        if r.samples_total:
            kept = f"{r.samples_total} sample(s) are safely in {self.slice_path}."
        else:
            kept = "No sample was captured yet."
        if self._io_fault:  # one line: what could not be written, what is safe, how to go on
            how = "Free some space, then resume" if "disk is full" in r.message else "Once it can be written, resume"
            r.message = f"{r.message}; {kept} {how} with: {self.resume_command()}"
        elif self._unopened:  # no resume to advise: the bench file's key to fix is in the message
            r.message = f"{r.message}; nothing was moved or captured"
        elif not self._before_motion and r.stop is not Stop.SAMPLE_CHANGED:  # that one says how to go on
            r.message = f"{r.message}\n{kept} {self.resume_hint()}"
        log.error(r.message, extra={"final": True})

    def resume_command(self) -> str:  # the arms' driver adds what a resume needs (GRBL in alarm, no switches)
        return f"gonio-capture --config {self.cfg.path} --out {self.out} --resume" + self.bench.resume_flags()

    def resume_hint(self) -> str:
        return f"Resume with: {self.resume_command()}"
