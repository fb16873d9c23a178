"""The run engine: checkpointed, resumable, interrupt-safe capture of a plan into ``DIR/slice.csv``.

The slice file is the checkpoint. Its metadata (written once, when the file is created) holds the plan, its
fingerprint, the dark level and the white-reference reading; every sample is appended (and fsynced) the moment
it is measured. A resume reads the file, checks that the plan is the same, reuses the stored calibration and
measures only the missing points, so no sample is lost and none is taken twice. ``DIR/capture.json`` is a
sidecar with the run history (status, times, unmeasurable points, end-of-run dark drift, auto-ranging);
``DIR/capture.log`` the log; ``DIR/simulator.log`` the simulator's log on a simulated bench.

With ``[detector].auto_range`` (the default) a saturated reading is taken again at shorter integration times and
converted back to the configured one (:mod:`acquisition.autorange`); the slice holds the converted values as
always. The dark level of every other setting is measured once and stored in the sidecar the moment it is
measured (``auto_range.darks``), as is the setting of every auto-ranged point (``auto_range.points``), so a
resumed capture converts with the same darks and the record counts every point once.

Ctrl-C and SIGTERM set a flag that the motion wait loops and the point loop check: the engine then parks the
arms, switches torque off and returns an "interrupted" result (a second signal aborts the parking; no signal
ever ends in a traceback, and one that arrives during the final dark reading or the parking still makes the exit
status 130 / 143). A hardware fault or a communication failure stops the same way, without parking when an axis
reports a fault; a full disk stops it with one line saying so (what was written stays consistent).

One capture owns an output folder: ``DIR/capture.lock`` is locked (``fcntl.flock``, :mod:`acquisition.lock`) for
the whole run, and everything the run will write is checked to be writable before anything moves. The slice
metadata holds a fingerprint of every setting that gives a sample its meaning (:mod:`acquisition.fingerprint`);
a resume with any of them changed is refused, naming each, and harmless changes are listed in the log. A resumed
run starts the simulator with ``--attempt N`` (N = earlier runs), so its noise and faults continue the random
streams instead of replaying the first run's.
"""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import sys
import tempfile
import threading
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from reconstruction.atomic import atomic_open, is_no_space
from reconstruction.slicefile import Slice, SliceError, SliceWriter, read_slice

from .autorange import AutoRanger, Ranged, read_clean, setting_key
from .calibration import Calibration, Reading, reference_rho
from .errors import (
    AcquisitionError,
    CaptureInterrupted,
    CommError,
    ConfigError,
    DeviceError,
    HardwareError,
    PlanError,
)
from .fingerprint import describe_differences, differences, fingerprint, settings
from .lock import OutLock
from .plan import Plan, Point, order_points, path_time, point_key, refine_points

log = logging.getLogger("acquisition.engine")

__all__ = ["RunEngine", "CaptureResult", "SLICE_NAME", "SIDECAR_NAME", "LOG_NAME"]

SLICE_NAME = "slice.csv"
SIDECAR_NAME = "capture.json"
LOG_NAME = "capture.log"
SIM_LOG_NAME = "simulator.log"

EXIT_OK, EXIT_FAILED, EXIT_USAGE = 0, 1, 2


def _software_version() -> str:
    try:
        from importlib.metadata import version

        return version("gonio-brdf")
    except Exception:  # pragma: no cover
        return "unknown"


@dataclass
class CaptureResult:
    """Outcome of a capture. Times in seconds; ``bench_time_s`` is the bench clock (simulated time on the
    simulator) over this run; ``motion_s`` the part spent moving to points (command to in position)."""

    out_dir: str
    slice_path: str
    status: str = "running"               # "complete" | "interrupted" | "failed"
    message: str = ""
    exit_code: int = EXIT_OK
    samples_total: int = 0
    samples_new: int = 0
    points_planned: int = 0
    unmeasurable: list[list[Any]] = field(default_factory=list)
    bench_time_s: float = 0.0
    bench_clock: str = "wall"             # "controller" when the bench reported its own clock
    motion_s: float = 0.0
    settle_s: float = 0.0
    read_s: float = 0.0
    wall_s: float = 0.0
    wall_per_sample_s: float = 0.0
    plan_motion_estimate_s: float = 0.0
    naive_motion_estimate_s: float = 0.0
    dark_drift: list[float] | None = None
    adaptive_rounds: int = 0
    auto_ranged: int = 0                  # points of the capture (all runs) read at a shorter integration time
    auto_range_settings: dict[str, int] = field(default_factory=dict)  # integration time (s) -> points
    auto_range_readings: int = 0          # readings discarded by auto-ranging in this run
    auto_range_overhead_s: float = 0.0    # their integration time plus new dark readings, this run (s)

    @property
    def ok(self) -> bool:
        return self.status == "complete"

    def raise_for_status(self) -> None:
        if not self.ok:
            raise AcquisitionError(self.message)


def _has_rows(path: Path) -> bool:
    """True if the slice file has its column header and at least one complete (newline-terminated) data row."""
    with open(path, "rb") as fh:
        data = fh.read()
    lines = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n").split(b"\n")  # any line ending
    complete = lines[:-1]  # the last element is "" or a torn line
    body = [ln for ln in complete if ln and not ln.startswith(b"#")]
    return len(body) >= 2  # column header + one row


def _parse_point(key: str) -> Point:
    """``"30.0,29.5"`` (a key of the sidecar's ``auto_range.points``) -> (30.0, 29.5)."""
    a, b = key.split(",")
    return (float(a), float(b))


def _atomic_json(path: Path, data: dict[str, Any]) -> None:
    with atomic_open(path, "w", encoding="utf-8") as fh:
        json.dump(data, fh, indent=1, sort_keys=True)
        fh.write("\n")


class _SignalGuard:
    """SIGINT/SIGTERM become flags, main thread only: the first asks the capture to stop after the current step
    (:meth:`check` raises :class:`CaptureInterrupted` there); a second also aborts the parking
    (:meth:`check_abort`). The handler itself never raises, so a signal arriving anywhere (in logging, in a write,
    in the clean-up) cannot end in a traceback; the exit status is the first signal's."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and threading.current_thread() is threading.main_thread()
        self.signum: int | None = None
        self.abort = False
        self._old: dict[int, Any] = {}

    def __enter__(self) -> _SignalGuard:
        if self.enabled:
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.getsignal(s)
                signal.signal(s, self._handler)
        return self

    def _handler(self, signum: int, frame: Any) -> None:
        name = signal.Signals(signum).name
        if self.signum is None:
            self.signum = signum
            log.warning("%s received: stopping after the current step (send it again to abort parking)", name)
        elif not self.abort:
            self.abort = True
            log.warning("%s received again: not waiting for the arms to park", name)

    def check(self) -> None:
        if self.signum is not None:
            raise CaptureInterrupted(f"interrupted by {signal.Signals(self.signum).name}", self.signum)

    def check_abort(self) -> None:
        """The cancel check while parking: only a second signal stops it."""
        if self.abort:
            assert self.signum is not None
            raise CaptureInterrupted(f"parking aborted by a second {signal.Signals(self.signum).name}", self.signum)

    def __exit__(self, *exc: object) -> None:
        for s, h in self._old.items():
            signal.signal(s, h)


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


class RunEngine:
    """Runs one capture of ``plan`` on ``bench`` into ``out``; see the module docstring."""

    def __init__(self, bench: Any, plan: Plan, out: str | Path, resume: bool = False, progress: bool | None = None,
                 handle_signals: bool = True) -> None:
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
        self._writer: SliceWriter | None = None
        self._done: dict[tuple[float, float], tuple[float, float, float, float]] = {}
        self._sidecar: dict[str, Any] = {}
        self._guard = _SignalGuard(False)
        self._pbar: Any = None
        self._t_last: float | None = None
        self._t0 = 0.0
        self._run_started = False
        self._ranger: AutoRanger | None = None
        self._before_motion = False  # the run stopped before the bench was open: nothing to resume or park
        self._io_fault = False  # an output file could not be written (a full disk)
        self._fingerprint: dict[str, Any] = {}
        self._settings: dict[str, Any] = {}
        self._setting_changes: list[tuple[str, Any, Any]] = []
        self._legacy_resume = False

    # -- public ---------------------------------------------------------------------------------------------------
    def run(self) -> CaptureResult:
        """Validate, lock the output folder, check it is writable, then capture. Raises PlanError / ConfigError
        before any motion (:class:`~acquisition.lock.OutDirLocked` when another capture holds the folder); every
        later failure is returned as a result with ``status`` and ``exit_code`` after the arms were made safe."""
        t_wall0 = time.monotonic()
        geom = self.bench.geometry
        chk = self.plan.validate(geom)  # before anything moves or opens
        self.result.points_planned = len(chk.measurable)
        self.result.unmeasurable = [[ti, to, why] for ti, to, why in chk.unmeasurable]
        est = self.plan.estimate(geom, self.cfg.detector.integration_time_s, chk.measurable)
        self.result.plan_motion_estimate_s = est["motion_s"]
        self.result.naive_motion_estimate_s = est["naive_motion_s"]
        self._fingerprint = fingerprint(self.cfg, self.plan.fingerprint())
        self._settings = settings(self.cfg)
        with _SignalGuard(self.handle_signals) as guard:  # from here on no signal ends in a traceback
            self._guard = guard
            self._make_out_dir()
            lock = OutLock(self.out)
            stale = lock.acquire()
            try:
                self._check_writable()
                self._run_locked(chk, est, existing=self._check_out_dir(), stale_pid=stale, t_wall0=t_wall0)
            finally:
                lock.release()
        return self.result

    def _run_locked(self, chk: Any, est: dict[str, float], existing: Slice | None, stale_pid: int | None,
                    t_wall0: float) -> None:
        self.result.samples_total = len(existing) if existing is not None else 0  # kept if the run stops early
        handler = self._attach_log()
        try:
            if stale_pid is not None:
                log.info("took over %s from PID %d, which ended without releasing it (killed?)",
                         self.out / "capture.lock", stale_pid)
            self._log_plan(chk, est)
            self._log_resume_checks()
            if existing is not None and self._sidecar.get("status") == "complete" \
                    and self._all_done(existing, chk.measurable):
                self.result.status = "complete"
                self.result.samples_total = len(existing)
                self.result.message = f"{self.slice_path} is already complete ({len(existing)} samples)"
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
            self._finish_run_record()
            self._report()
            logging.getLogger("acquisition").removeHandler(handler)
            handler.close()

    # -- setup ----------------------------------------------------------------------------------------------------
    def _make_out_dir(self) -> None:
        """Create the output directory; a path that is a file or cannot be created is a :class:`PlanError`."""
        try:
            self.out.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise PlanError(out_dir_problem(self.out, e)) from None

    def _check_writable(self) -> None:
        """Everything this run writes must be writable, checked before anything moves: the folder (run record,
        new files), and the slice, log and simulator log it appends to."""
        try:
            fd, tmp = tempfile.mkstemp(prefix=".write-test.", dir=self.out)
            os.close(fd)
            os.unlink(tmp)
        except OSError as e:
            raise PlanError(f"--out {self.out}: cannot write in the output folder ({e.strerror or e})") from None
        for p in (self.slice_path, self.out / LOG_NAME, self.out / SIM_LOG_NAME):
            if not p.exists():
                continue
            try:
                os.close(os.open(p, os.O_WRONLY | os.O_APPEND))
            except OSError as e:
                raise PlanError(f"--out {self.out}: {p.name} cannot be written ({e.strerror or e}); a capture "
                                "appends to it") from None

    def _check_fingerprint(self, meta: dict[str, Any]) -> None:
        """Refuse a resume whose config changes the meaning of a sample; remember the harmless changes."""
        old = meta.get("config_fingerprint")
        if not isinstance(old, dict):
            self._legacy_resume = True
            return
        diffs = differences(old, self._fingerprint)
        if diffs:
            plan = [d for d in diffs if d[0].startswith(("[plan", "plan "))]
            what = ("plan" if len(plan) == len(diffs) else "plan and configuration" if plan else "configuration")
            raise PlanError(f"cannot resume: {self.slice_path} was captured with a different {what}: "
                            f"{describe_differences(diffs)}; restore {'it' if len(diffs) == 1 else 'them'} or "
                            "choose another --out")
        old_settings = meta.get("config_settings")
        if isinstance(old_settings, dict):
            self._setting_changes = differences(old_settings, self._settings)

    def _log_resume_checks(self) -> None:
        if self._setting_changes:
            log.info("resuming with changed setting(s) that cannot change a sample: %s",
                     describe_differences(self._setting_changes))
        if self._legacy_resume:
            log.info("%s has no configuration fingerprint (an older capture): only the plan, calibration mode, "
                     "detector type and integration time were checked", self.slice_path)

    def _check_out_dir(self) -> Slice | None:
        if self.sidecar_path.exists():
            try:
                self._sidecar = json.loads(self.sidecar_path.read_text(encoding="utf-8"))
            except (OSError, json.JSONDecodeError) as e:
                log.warning("%s unreadable (%s); starting a new run record", self.sidecar_path, e)
                self._sidecar = {}
        if self.slice_path.exists() and not _has_rows(self.slice_path):
            # killed before the first sample was complete: nothing to keep (the calibration is re-measured)
            log.info("%s holds no complete sample; starting it again", self.slice_path)
            self.slice_path.unlink()
        if not self.slice_path.exists():
            if self.resume:
                log.info("nothing to resume in %s: starting a new capture", self.out)
            self._sidecar = {k: v for k, v in self._sidecar.items() if k == "runs"}
            return None
        if not self.resume:
            raise PlanError(f"{self.out} already holds a capture ({self.slice_path}); continue it with --resume, "
                            "or choose another --out")
        try:
            import warnings

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                existing = read_slice(self.slice_path)
        except SliceError as e:
            raise PlanError(f"cannot resume: {e}") from None
        meta = existing.meta
        self._check_fingerprint(meta)
        fp = meta.get("plan_fingerprint")
        if fp != self.plan.fingerprint():
            raise PlanError(f"cannot resume: {self.slice_path} was captured with a different plan (fingerprint "
                            f"{fp}, the config now gives {self.plan.fingerprint()}); restore the plan or choose "
                            "another --out")
        kind = existing.kind
        if (self.cfg.detector.type == "photodiode") != (kind == "grey"):
            raise PlanError(f"cannot resume: {self.slice_path} has value columns {existing.channels[:4]}, but a "
                            f"{self.cfg.detector.type} gives {'one value column' if kind != 'grey' else 'spectra'}")
        cal = meta.get("calibration", {})
        if cal.get("mode") != self.cfg.calibration.mode:
            raise PlanError(f"cannot resume: {self.slice_path} used {cal.get('mode')!r} calibration, the config "
                            f"says {self.cfg.calibration.mode!r}")
        if meta.get("detector", {}).get("type") != self.cfg.detector.type:
            raise PlanError(f"cannot resume: {self.slice_path} was captured with a "
                            f"{meta.get('detector', {}).get('type')}, the config has a {self.cfg.detector.type}")
        t_was = meta.get("detector", {}).get("integration_time_s")
        t_now = self.cfg.detector.integration_time_s
        if t_was is not None and not math.isclose(float(t_was), t_now, rel_tol=1e-9):
            raise PlanError(f"cannot resume: {self.slice_path} was calibrated at [detector].integration_time_s = "
                            f"{float(t_was):g} s, the config now says {t_now:g} s; restore it or choose another --out")
        return existing

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
        log.info("estimated motion time %.2f s in plan order vs %.2f s in naive order; total %.2f s",
                 est["motion_s"], est["naive_motion_s"], est["total_s"])

    @staticmethod
    def _all_done(existing: Slice, pts: list[Point]) -> bool:
        have = {point_key((a, b)) for a, b in zip(existing.theta_i_deg, existing.theta_o_deg, strict=True)}
        return all(point_key(p) in have for p in pts)

    # -- run record (sidecar) ---------------------------------------------------------------------------------------
    def _start_run_record(self, existing: Slice | None) -> None:
        sc = self._sidecar
        sc.setdefault("runs", [])
        sc.update({
            "config": str(self.cfg.path),
            "plan": self.plan.to_meta(),
            "plan_fingerprint": self.plan.fingerprint(),
            "points_planned": self.result.points_planned,
            "unmeasurable": self.result.unmeasurable,
            "estimate": {"motion_s": self.result.plan_motion_estimate_s,
                         "naive_motion_s": self.result.naive_motion_estimate_s},
            "status": "running",
        })
        sc["runs"].append({"started_unix": time.time(), "resume": existing is not None,
                           "samples_before": 0 if existing is None else len(existing), "pid": os.getpid()})
        _atomic_json(self.sidecar_path, sc)
        self._run_started = True
        attempt = len(sc["runs"]) - 1
        if attempt and hasattr(self.bench, "sim_args"):  # the simulator's random streams continue, not replay
            self.bench.sim_args = ("--attempt", str(attempt))

    def _finish_run_record(self) -> None:
        if not self._run_started:
            return
        r = self.result
        run = self._sidecar["runs"][-1]
        run.update({"ended_unix": time.time(), "status": r.status, "message": r.message,
                    "samples_new": r.samples_new, "samples_total": r.samples_total, "bench_time_s": r.bench_time_s,
                    "bench_clock": r.bench_clock, "motion_s": r.motion_s, "settle_s": r.settle_s,
                    "read_s": r.read_s, "wall_s": r.wall_s, "wall_per_sample_s": r.wall_per_sample_s})
        self._sidecar["status"] = r.status
        ar = self._sidecar.get("auto_range")
        if ar is not None:
            run["auto_range"] = {"readings_discarded": r.auto_range_readings, "overhead_s": r.auto_range_overhead_s}
            ar["overhead_s"] = float(sum(x.get("auto_range", {}).get("overhead_s", 0.0)
                                         for x in self._sidecar["runs"]))
        if r.dark_drift is not None:
            self._sidecar["dark_drift"] = r.dark_drift
        runs = self._sidecar["runs"]
        self._sidecar["totals"] = {k: float(sum(x.get(k, 0.0) for x in runs))
                                   for k in ("bench_time_s", "motion_s", "settle_s", "read_s", "wall_s")}
        try:
            _atomic_json(self.sidecar_path, self._sidecar)
        except OSError as e:  # pragma: no cover
            log.error("cannot write %s: %s", self.sidecar_path, e)

    # -- the capture ------------------------------------------------------------------------------------------------
    def _capture(self, existing: Slice | None, measurable: list[Point]) -> None:
        r = self.result
        bench = self.bench
        opened_here = False
        hardware_fault = False
        try:
            try:
                self._guard.check()  # a signal during the start-up: stop before anything opens
                if not bench.is_open:
                    if bench.cfg.bench.transport == "simulated":
                        bench.simulator_log = self.out / SIM_LOG_NAME
                    bench.open()
                    opened_here = True
                bench.motion.cancel = self._guard.check
                r.bench_clock = "controller" if bench.has_clock else "wall"
                t0 = bench.now()
                self._t_last = t0
                self._t0 = t0
                try:
                    self._setup_auto_range(existing)
                    cal = self._calibration(existing)
                    self._prune_ranged_points()
                    self._measure_all(measurable, cal)
                    if self.plan.adaptive is not None:
                        self._adaptive(measurable, cal)
                    if self._ranger is not None:
                        self._ranger.restore()
                        self._log_auto_range()
                    if self.plan.dark_at_end:
                        self._guard.check()
                        d_end = self._read_checked(self.cfg.detector.dark_repeats, "dark reading", dark=True)
                        self._guard.check()  # a signal during the final dark: stopped; a resume measures it again
                        drift = d_end.mean - cal.dark.mean
                        r.dark_drift = [float(x) for x in drift]
                        noise = cal.dark.std_of_mean + d_end.std_of_mean
                        lvl = "warning" if np.any(np.abs(drift) > 3 * np.maximum(noise, 1e-9)) else "info"
                        getattr(log, lvl)("dark level drift over the capture: %s counts (start %s)",
                                          np.round(drift, 3).tolist(), np.round(cal.dark.mean, 3).tolist())
                finally:
                    try:
                        r.bench_time_s = bench.now() - t0
                    except Exception:  # the link may be gone after a failure: keep the last known time
                        if self._t_last is not None:
                            r.bench_time_s = self._t_last - t0
                r.status = "complete"
                r.message = (f"captured {r.samples_new} new sample(s); {r.samples_total} in {self.slice_path}")
            except CaptureInterrupted as e:
                r.status, r.exit_code = "interrupted", 128 + (e.signum or signal.SIGINT)
                r.message = f"capture {e}"
            except KeyboardInterrupt:
                r.status, r.exit_code = "interrupted", 128 + signal.SIGINT
                r.message = "capture interrupted"
            except HardwareError as e:
                hardware_fault = True
                r.status, r.exit_code = "failed", EXIT_FAILED
                r.message = f"hardware fault: {e}"
            except (CommError, DeviceError) as e:
                r.status, r.exit_code = "failed", EXIT_FAILED
                r.message = f"bench failure: {e}"
            except ConfigError as e:  # the simulator refused its sections of the config, when it was started
                self._before_motion = True
                r.status, r.exit_code = "failed", EXIT_USAGE
                r.message = f"{e}\nnothing was moved."
            except PlanError as e:
                r.status, r.exit_code = "failed", EXIT_USAGE
                r.message = str(e)
            except OSError as e:  # the slice, the run record or the log cannot be written (a full disk)
                self._io_failure(e)
            except Exception as e:  # a bug or an unforeseen device reply: still stop safely and stay resumable
                log.exception("unexpected error")
                r.status, r.exit_code = "failed", EXIT_FAILED
                r.message = f"unexpected error: {e!r} (details in {self.out / LOG_NAME})"
        finally:
            if self._pbar is not None:
                self._pbar.close()
            if self._writer is not None:
                try:
                    self._writer.close()
                except OSError as e:  # every row was fsynced when appended; only the final sync failed
                    log.info("closing %s: %s", self.slice_path, e)
            if r.status != "complete" and not hardware_fault:
                self._restore_integration_time()
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
            if self._guard.signum is not None and r.status == "complete":
                # everything was measured, but the signal arrived while stopping: say so in the exit status
                name = signal.Signals(self._guard.signum).name
                r.exit_code = 128 + self._guard.signum
                r.message += f"; {name} arrived while parking the arms: check that they are parked"

    def _io_failure(self, e: OSError) -> None:
        """The run stops because an output file cannot be written; one line says which and why."""
        r = self.result
        r.status, r.exit_code = "failed", EXIT_FAILED
        self._io_fault = True
        where = e.filename or "an output file"
        if is_no_space(e):
            r.message = (f"the disk is full (or a file size limit was reached): cannot write {where} "
                         f"({e.strerror or e})")
        else:
            r.message = f"cannot write {where} ({e.strerror or e})"

    def _read_checked(self, n: int, what: str, dark: bool = False) -> Reading:
        """A reading without saturated repeats at the present setting (re-read up to ``retries`` times; then a
        DeviceError)."""
        det = self.bench.detector
        read = det.dark if dark else det.read
        for attempt in range(self.cfg.motion.retries + 1):
            # read again around transient clips (in pieces) after the first attempt
            rd = read(n) if attempt == 0 else read_clean(read, n, self.cfg.motion.retries)[0]
            if not rd.saturated:
                return rd
            log.warning("%s: %d of %d repeats saturated (attempt %d); reading again", what, rd.saturated, n,
                        attempt + 1)
        hint = "" if dark or self.cfg.detector.auto_range else ", or set [detector].auto_range = true"
        raise DeviceError(f"{what}: the detector saturates ({det.saturation:g} counts); reduce "
                          f"[detector].integration_time_s or the gain{hint}")

    def _read_point(self, n: int, what: str, start: int | None = None) -> tuple[Reading, Ranged | None]:
        """A reading with the source on, in counts at the configured integration time: auto-ranged when
        ``[detector].auto_range`` (then also the :class:`Ranged` record), else :meth:`_read_checked`."""
        if self._ranger is None:
            return self._read_checked(n, what), None
        rg = self._ranger.read(n, what, start)
        self.result.auto_range_readings += rg.readings - 1
        self.result.auto_range_overhead_s += rg.overhead_s
        return rg.reading, rg

    # -- auto-ranging record (sidecar "auto_range") ------------------------------------------------------------
    def _setup_auto_range(self, existing: Slice | None) -> None:
        """Create the ranger; on a resume, reload the darks per setting and the record of ranged points."""
        d = self.cfg.detector
        if not d.auto_range:
            self._ranger = None
            return
        det = self.bench.detector
        rec = self._sidecar.get("auto_range")
        same = isinstance(rec, dict) and math.isclose(float(rec.get("reference_integration_time_s", -1.0)),
                                                      d.integration_time_s, rel_tol=1e-9)
        if existing is None or not same:
            if existing is not None:
                log.info("auto-ranging: no record of earlier runs in %s; darks at other settings are measured "
                         "again when needed", self.sidecar_path)
            rec = {"darks": {}, "points": {}}
        assert isinstance(rec, dict)
        rec.setdefault("darks", {})
        rec.setdefault("points", {})
        ranger = AutoRanger(det, d.integration_time_s, d.min_integration_time_s,
                            read_dark=lambda: self._read_checked(
                                d.dark_repeats, f"dark reading at t_int = {det.integration_time_s:g} s", dark=True),
                            on_dark=self._store_dark, retries=self.cfg.motion.retries)
        rec.update(enabled=True, reference_integration_time_s=d.integration_time_s,
                   min_integration_time_s=d.min_integration_time_s, ladder_s=ranger.ladder)
        for key, m in rec["darks"].items():
            ranger.darks[key] = Reading.from_meta(m)
        if rec["darks"]:
            log.info("auto-ranging: reusing the dark level at %s s from %s", ", ".join(sorted(rec["darks"])),
                     self.sidecar_path)
        self._sidecar["auto_range"] = rec
        self._ranger = ranger
        self._update_range_counts()

    def _store_dark(self, t: float, rd: Reading) -> None:
        """Keep a dark at a new setting in the sidecar at once (a resume converts with the same darks)."""
        self._sidecar["auto_range"]["darks"][setting_key(t)] = {"integration_time_s": t, **rd.to_meta()}
        _atomic_json(self.sidecar_path, self._sidecar)

    def _update_range_counts(self) -> None:
        rec = self._sidecar["auto_range"]
        counts: dict[str, int] = {}
        for t in rec["points"].values():
            counts[setting_key(t)] = counts.get(setting_key(t), 0) + 1
        rec["settings"] = dict(sorted(counts.items(), key=lambda kv: -float(kv[0])))
        rec["ranged_points"] = len(rec["points"])
        self.result.auto_ranged = len(rec["points"])
        self.result.auto_range_settings = dict(rec["settings"])

    def _record_setting(self, ti: float, to: float, rg: Ranged | None) -> None:
        """Record (before the sample is appended) the integration time of an auto-ranged point; keyed by the
        point, so a point measured again after a kill is counted once."""
        if rg is None:
            return
        points = self._sidecar["auto_range"]["points"]
        key = f"{ti!r},{to!r}"
        if rg.ranged:
            log.info("point (%g, %g): auto-ranged to t_int = %g s (%d reading(s))", ti, to, rg.integration_time_s,
                     rg.readings)
            points[key] = rg.integration_time_s
        elif key in points:
            del points[key]
        else:
            return
        self._update_range_counts()
        _atomic_json(self.sidecar_path, self._sidecar)

    def _prune_ranged_points(self) -> None:
        """Drop records of ranged points that never reached the slice (killed between record and append)."""
        if self._ranger is None:
            return
        points = self._sidecar["auto_range"]["points"]
        stale = [k for k in points if point_key(_parse_point(k)) not in self._done]
        for k in stale:
            del points[k]
        self._update_range_counts()

    def _log_auto_range(self) -> None:
        r = self.result
        if not r.auto_ranged and not r.auto_range_readings:
            return
        settings = ", ".join(f"{k} s: {v}" for k, v in r.auto_range_settings.items())
        log.info("auto-ranging: %d point(s) of the capture read at shorter integration times (%s); this run "
                 "discarded %d reading(s) and spent %.3f s of extra integration (dark readings included)",
                 r.auto_ranged, settings or "none", r.auto_range_readings, r.auto_range_overhead_s)

    def _restore_integration_time(self) -> None:
        """Best effort after a failure: leave the detector at the configured integration time."""
        ranger, link = self._ranger, self.bench.link
        if ranger is None or not self.bench.is_open or link is None or link.dead:
            return
        try:
            ranger.restore()
        except Exception as e:  # noqa: BLE001 - the bench is being made safe; the next connect sets INT again
            log.warning("could not restore the integration time: %s", e)

    def _calibration(self, existing: Slice | None) -> Calibration:
        bench = self.bench
        c = self.cfg.calibration
        det = bench.detector
        rho = reference_rho(c.reference_reflectance, c.reference_spectrum, det.wavelengths_nm)
        ranger = self._ranger
        if existing is not None:
            channels = det.channels
            if sorted(existing.channels) != sorted(channels):
                raise PlanError(f"cannot resume: {self.slice_path} has channels {existing.channels[:4]}..., the "
                                f"detector gives {channels[:4]}...")
            m = existing.meta["calibration"]
            cal = Calibration(c.mode, Reading.from_meta(m["dark"]),
                              Reading.from_meta(m["reference_reading"]) if "reference_reading" in m else None,
                              np.asarray(m["rho_ref"]) if "rho_ref" in m else None,
                              float(m.get("reference_theta_o_deg", c.reference_theta_o_deg)), m.get("k_counts"))
            for ti, to, v, s in zip(existing.theta_i_deg, existing.theta_o_deg, existing.values.mean(axis=1),
                                    existing.std.mean(axis=1), strict=True):
                self._done[point_key((ti, to))] = (float(ti), float(to), float(v), float(s))
            self._writer = SliceWriter(self.slice_path, channels)
            self.result.samples_total = len(self._done)
            if ranger is not None:
                ranger.ref_dark = cal.dark
            det.set_sample("TARGET")
            log.info("resuming: %d samples already in %s; calibration reused from its metadata", len(self._done),
                     self.slice_path)
            return cal
        log.info("measuring the dark level (%d repeats, source off)", self.cfg.detector.dark_repeats)
        dark = self._read_checked(self.cfg.detector.dark_repeats, "dark reading", dark=True)
        if ranger is not None:
            ranger.ref_dark = dark
        t_ref_read = self.cfg.detector.integration_time_s
        if c.mode == "relative":
            log.info("measuring the white reference at (%g, %g) (%d repeats)", c.reference_theta_i_deg,
                     c.reference_theta_o_deg, c.reference_repeats)
            det.set_sample("REF")
            try:
                bench.move(c.reference_theta_i_deg, c.reference_theta_o_deg)
                bench.settle()
                ref, rg = self._read_point(c.reference_repeats, "white reference", start=0)
                if rg is not None:
                    t_ref_read = rg.integration_time_s
                    self._sidecar["auto_range"]["white_reference_integration_time_s"] = t_ref_read
                    if rg.ranged:
                        log.info("white reference: auto-ranged to t_int = %g s", t_ref_read)
            finally:
                det.set_sample("TARGET")
            cal = Calibration("relative", dark, ref, rho, c.reference_theta_o_deg)
            try:
                cal.scale(c.reference_theta_o_deg)  # raises if the reference reads no signal
            except ValueError as e:
                raise DeviceError(f"white reference at ({c.reference_theta_i_deg:g}, {c.reference_theta_o_deg:g}): "
                                  f"{e} (reference {ref.mean.tolist()[:4]}, dark {dark.mean.tolist()[:4]} counts)"
                                  ) from None
        else:
            assert c.source_power is not None and c.detector_solid_angle_sr is not None
            cal = Calibration("absolute", dark, k_counts=c.source_power * c.detector_solid_angle_sr)
        log.info("dark %s counts; %s", np.round(dark.mean, 3).tolist()[:8],
                 f"reference {np.round(cal.reference.mean, 3).tolist()[:8]} counts" if cal.reference else
                 f"K = {cal.k_counts:g} counts")
        meta = {
            "bench": str(self.cfg.path),
            "bench_name": self.cfg.bench.name,
            "transport": self.cfg.bench.transport,
            "software_version": _software_version(),
            "quantity": "brdf",
            "calibration": {**c.to_meta(), **cal.to_meta()},
            "detector": {"type": det.type, "integration_time_s": self.cfg.detector.integration_time_s,
                         "saturation": det.saturation, "auto_range": self.cfg.detector.auto_range},
            "plan": self.plan.to_meta(),
            "plan_fingerprint": self.plan.fingerprint(),
            "config_fingerprint": self._fingerprint,
            "config_settings": self._settings,
            "unmeasurable": self.result.unmeasurable,
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        if self.cfg.detector.auto_range:
            meta["detector"]["min_integration_time_s"] = self.cfg.detector.min_integration_time_s
            if c.mode == "relative":
                meta["calibration"]["reference_reading_integration_time_s"] = t_ref_read
        if self.cfg.sample_name:
            meta["material"] = self.cfg.sample_name
        self._writer = SliceWriter(self.slice_path, det.channels, meta)
        return cal

    def _bar_enabled(self) -> bool:
        return sys.stderr.isatty() if self.progress is None else bool(self.progress)

    def _progress(self, total: int, initial: int) -> Any:
        if self._pbar is None:
            from tqdm import tqdm

            self._pbar = tqdm(total=total, initial=initial, unit="pt", desc="capture",
                              disable=not self._bar_enabled(), dynamic_ncols=True)
        else:
            self._pbar.total = total
            self._pbar.refresh()
        return self._pbar

    def _measure_all(self, points: list[Point], cal: Calibration) -> None:
        todo = [p for p in points if point_key(p) not in self._done]
        n_known = len(self._done)
        pbar = self._progress(n_known + len(todo), n_known)
        if not todo:
            return
        bench = self.bench
        geom = bench.geometry
        start = bench.positions()
        if self.plan.order == "optimized":
            todo = order_points(todo, geom, start=start)
        log.info("%d point(s) to measure; estimated motion %.2f s", len(todo), path_time(todo, geom, start))
        n = self.plan.repeats
        for ti, to in todo:
            self._guard.check()
            self._measure_point(ti, to, n, cal)
            pbar.update(1)

    def _measure_point(self, ti: float, to: float, n: int, cal: Calibration) -> None:
        bench = self.bench
        r = self.result
        t0 = self._t_last if self._t_last is not None else bench.now()
        bench.move(ti, to)
        t1 = bench.now()
        bench.settle()
        rd, rg = self._read_point(n, f"point ({ti:g}, {to:g})")
        f, fs = cal.brdf(rd, to)
        self._record_setting(ti, to, rg)
        assert self._writer is not None
        self._writer.append(ti, to, f.tolist(), fs.tolist(), n, time.time())
        t2 = bench.now()
        self._t_last = t2
        r.motion_s += t1 - t0
        r.settle_s += self.cfg.motion.settle_s
        r.read_s += max(t2 - t1 - self.cfg.motion.settle_s, 0.0)
        self._done[point_key((ti, to))] = (ti, to, float(np.mean(f)), float(np.mean(fs)))
        r.samples_new += 1
        r.samples_total = len(self._done)

    def _adaptive(self, coarse: list[Point], cal: Calibration) -> None:
        a = self.plan.adaptive
        assert a is not None
        known = {point_key(p) for p in coarse}
        t_start = self._t0 - self._previous_bench_time()  # the budget counts every run of this capture
        for rnd in range(1, a.max_rounds + 1):
            samples: dict[float, list[tuple[float, float, float]]] = {}
            for k in known:
                ti, to, v, s = self._done[k]
                samples.setdefault(ti, []).append((to, v, s))
            new = refine_points(samples, self.bench.geometry, a.tolerance, a.min_step_deg, known)
            if a.max_points and len(known) + len(new) > a.max_points:
                new = new[: max(a.max_points - len(known), 0)]
                log.info("adaptive: point limit %d reached", a.max_points)
            if not new:
                log.info("adaptive: converged after %d round(s) (tolerance %g)", rnd - 1, a.tolerance)
                break
            if a.time_budget_s and self.bench.now() - t_start > a.time_budget_s:
                log.info("adaptive: time budget %g s used up before round %d", a.time_budget_s, rnd)
                break
            log.info("adaptive round %d: %d new point(s)", rnd, len(new))
            self._measure_all(new, cal)
            known |= {point_key(p) for p in new}
            self.result.adaptive_rounds = rnd
            if a.max_points and len(known) >= a.max_points:
                break

    def _previous_bench_time(self) -> float:
        return float(sum(run.get("bench_time_s", 0.0) for run in self._sidecar.get("runs", [])[:-1]))

    # -- report -------------------------------------------------------------------------------------------------------
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
        elif not self._before_motion:
            r.message = f"{r.message}\n{kept} {self.resume_hint()}"
        log.error(r.message, extra={"final": True})

    def resume_command(self) -> str:
        return f"gonio-capture --config {self.cfg.path} --out {self.out} --resume"

    def resume_hint(self) -> str:
        return f"Resume with: {self.resume_command()}"


def out_dir_problem(out: Path, err: OSError | None = None) -> str:
    """Why ``out`` cannot be the output directory: one line naming it (``err``: what creating it raised)."""
    for p in (out, *out.parents):
        if p.exists() and not p.is_dir():
            return f"{out}: is a file, not a directory" if p == out else f"{out}: {p} is a file, not a directory"
    why = (err.strerror or str(err)) if err is not None else "cannot be created"
    return f"{out}: cannot create the output directory: {why}"


def result_dict(r: CaptureResult) -> dict[str, Any]:
    """The result as a JSON-able dict."""
    d = asdict(r)
    for k, v in d.items():
        if isinstance(v, float) and not math.isfinite(v):
            d[k] = None
    return d
