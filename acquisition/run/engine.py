"""The engine: runs a capture plan (a generator of :mod:`acquisition.plans.messages`) against the device protocols of
:mod:`acquisition.devices.protocols`, and knows nothing of Dynamixel servos, serial controllers or simulators.

For each message it does one thing and sends the plan its reply: move (and account the motion time), settle,
read (auto-ranged when ``[detector].auto_range``: :mod:`acquisition.devices.autorange`; saturated repeats are read
again), read the dark level, select the sample, convert with a calibration, save a sample (f_r appended to the
slice through the sink, the auto-ranged setting recorded in the run record first), stop at a checkpoint when
Ctrl-C / SIGTERM asked, tell where the arms are and what time it is. An exception raised while carrying out a
message is thrown into the plan, so its ``finally`` clauses run (the white reference is swapped out again).

The capture as a whole (output folder, lock, resume checks, the run record, opening and making the bench safe,
the outcome) is :class:`acquisition.run.capture.RunEngine`; ``gonio-capture --check`` runs the same plans with
:mod:`acquisition.run.dryrun`.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from dataclasses import replace
from typing import Any, Protocol

import numpy as np

from acquisition.calibration import Calibration, Reading
from acquisition.devices.autorange import AutoRanger, ranged_wording, read_clean
from acquisition.devices.protocols import Devices
from acquisition.errors import DeviceError
from acquisition.plans.messages import (
    Announce,
    Calibrate,
    Checkpoint,
    Convert,
    Dark,
    Move,
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
from acquisition.plans.reference import reference_doubts
from acquisition.run.record import CaptureResult, RunRecord

log = logging.getLogger("acquisition.engine")

__all__ = ["Engine", "Sink", "Bar"]


class Sink(Protocol):
    """Where saved samples go (the slice file): ``open`` once the calibration is known, then ``append``."""

    def open(self, calibration: Calibration, reference_integration_time_s: float | None) -> None: ...

    def append(self, theta_i_deg: float, theta_o_deg: float, f: list[float], std: list[float], repeats: int
               ) -> None: ...


class Bar(Protocol):
    """A progress display: the number of points (``announce``), one more done (``advance``)."""

    def announce(self, total: int, done: int) -> None: ...

    def advance(self) -> None: ...


class _NoGuard:
    def check(self) -> None:
        pass


class Engine:
    """Interprets plan messages against ``devices``; see the module docstring.

    ``settle_s``: ``[motion].settle_s``; ``retries``: re-reads of a saturated reading; ``result``: where the run's
    figures go (times, samples, auto-ranging); ``sink``: the slice; ``record``: the run record (its
    ``auto_range`` is kept up to date); ``auto_range``: (t_ref, t_min, dark_repeats) to auto-range the detector
    (None: it is not); ``guard``: its ``check()`` raises at a checkpoint when a signal asked to stop;
    ``account``: measure motion, settle and read times on the bench clock (a dry run's is its time model);
    ``convert``: convert readings to f_r and save them (off in a dry run, whose samples are zeros).
    """

    def __init__(self, devices: Devices, *, settle_s: float, retries: int, result: CaptureResult | None = None,
                 sink: Sink | None = None, record: RunRecord | None = None,
                 auto_range: tuple[float, float, int] | None = None, guard: Any = None, bar: Bar | None = None,
                 account: bool = True, auto_range_hint: bool = True, samples_total: int = 0,
                 convert: bool = True, gains: tuple[float, ...] | None = None) -> None:
        self.dev = devices
        self.settle_s = settle_s
        self.retries = retries
        self.result = result if result is not None else CaptureResult("", "")
        self.sink = sink
        self.record = record
        self.guard = guard if guard is not None else _NoGuard()
        self.bar = bar
        self.account = account
        self.convert = convert
        self.goal: tuple[float, float] | None = None  # the last goal the arms reached in this run
        self.auto_range_hint = auto_range_hint
        self.calibration: Calibration | None = None
        self.ranger: AutoRanger | None = None
        self.t_last: float | None = None
        self._t_move = (0.0, 0.0)
        self.result.samples_total = samples_total
        if auto_range is not None:
            self._setup_ranger(*auto_range, gains=gains)
        self._handlers: dict[type, Callable[[Any], Any]] = {
            Move: self._move, Settle: self._settle, Wait: self._wait, Read: self._read, ReadAt: self._read_at,
            Dark: self._dark,
            SelectSample: self._select, Calibrate: self._calibrate, Save: self._save, Convert: self._convert,
            Checkpoint: self._checkpoint,
            Where: self._where, Now: self._now, Announce: self._announce, RestoreSetting: self._restore,
            Tally: self._tally, UseReference: self._use_reference,
        }

    # -- the loop -----------------------------------------------------------------------------------------------
    def run(self, plan: Any) -> Any:
        """Run ``plan`` to its end; returns its return value. An exception of a message is thrown into the plan;
        one the plan does not handle propagates."""
        reply: Any = None
        exc: BaseException | None = None
        handlers = self._handlers
        while True:
            try:
                msg = plan.send(reply) if exc is None else plan.throw(exc)
            except StopIteration as stop:
                return stop.value
            exc = None
            try:
                reply = handlers[type(msg)](msg)
            except KeyError:
                if type(msg) in handlers:
                    raise
                exc = TypeError(f"the engine has no handler for the message {msg!r}")
                reply = None
            except BaseException as e:  # noqa: BLE001 - thrown into the plan, re-raised if it does not handle it
                exc = e
                reply = None

    # -- motion and time --------------------------------------------------------------------------------------
    def _move(self, m: Move) -> Any:
        if m.checkpoint:
            self.guard.check()
        self.goal = None
        if not self.account:
            status = self.dev.axes.set(m.theta_i_deg, m.theta_o_deg)
        else:
            clock = self.dev.clock
            t0 = self.t_last if self.t_last is not None else clock.now()
            status = self.dev.axes.set(m.theta_i_deg, m.theta_o_deg)
            self._t_move = (t0, clock.now())
        if status.done and status.success:
            self.goal = (m.theta_i_deg, m.theta_o_deg)
        return status

    def _settle(self, m: Settle) -> None:
        self.dev.clock.dwell(self.settle_s)

    def _wait(self, m: Wait) -> None:
        self.dev.clock.dwell(m.seconds)

    def _where(self, m: Where) -> tuple[float, float]:
        """The goal the arms last reached in this run (what the plan ordered them to, so a dry run and the capture
        order the points from the same place), else their present positions."""
        return self.goal if self.goal is not None else self.dev.axes.positions()

    def _now(self, m: Now) -> float:
        return self.dev.clock.now()

    def _checkpoint(self, m: Checkpoint) -> None:
        self.guard.check()

    # -- detector ------------------------------------------------------------------------------------------------
    def read_checked(self, n: int, what: str, dark: bool = False, first: Reading | None = None) -> Reading:
        """A reading without saturated repeats at the present setting (re-read up to ``retries`` times; then a
        DeviceError). ``first``: the first attempt, already read."""
        det = self.dev.detector
        read = det.dark if dark else det.read
        for attempt in range(self.retries + 1):
            # read again around transient clips (in pieces) after the first attempt
            if attempt == 0:
                rd = first if first is not None else read(n)
            else:
                rd = read_clean(read, n, self.retries)[0]
            if not rd.saturated:
                return rd
            log.warning("%s: %d of %d repeats saturated (attempt %d); reading again", what, rd.saturated, n,
                        attempt + 1)
        hint = "" if dark or not self.auto_range_hint else ", or set [detector].auto_range = true"
        raise DeviceError(f"{what}: the detector saturates ({det.saturation:g} counts); reduce "
                          f"[detector].integration_time_s or the gain{hint}")

    def _read(self, m: Read) -> tuple[Reading, Any]:
        if self.ranger is None:
            rd = self.dev.detector.read(m.repeats)
            return (rd if not rd.saturated else self.read_checked(m.repeats, m.label, first=rd)), None
        rg = self.ranger.read(m.repeats, m.label, m.rung, m.point)
        self.result.auto_range_readings += rg.readings - 1
        self.result.auto_range_overhead_s += rg.overhead_s
        return rg.reading, rg

    def _read_at(self, m: ReadAt) -> tuple[Reading, float | None]:
        if self.ranger is None:
            return self.dev.detector.read(m.repeats), None
        self.ranger.set_setting(m.setting)
        return self.dev.detector.read(m.repeats), self.ranger.gain_of(m.setting)  # calibration time (estimated)

    def _dark(self, m: Dark) -> Reading:
        if m.setting is not None and self.ranger is not None:
            return self.ranger.dark_at(m.setting)
        rd = self.read_checked(m.repeats, m.what, dark=True)
        if m.calibration and self.ranger is not None:
            self.ranger.ref_dark = rd
        return rd

    def _select(self, m: SelectSample) -> bool:
        """Put the sample or the reference in the beam; True when the operator was asked to (no changer)."""
        return bool(self.dev.detector.set_sample(m.which))

    # -- auto-ranging --------------------------------------------------------------------------------------------
    def _setup_ranger(self, t_ref: float, t_min: float, dark_repeats: int, gains: tuple[float, ...] | None = None
                      ) -> None:
        det = self.dev.detector
        rec = self.record.auto_range if self.record is not None else None
        self.ranger = AutoRanger(det, t_ref, t_min,
                                 read_dark=lambda: self.read_checked(
                                     dark_repeats, f"dark reading at t_int = {det.integration_time_s:g} s", dark=True),
                                 on_dark=self._store_dark, retries=self.retries, gains=gains)
        if rec is not None:
            rec.ladder_s = self.ranger.ladder
            rec.ladder_gains = self.ranger.gains
            self.ranger.darks.update(rec.dark_readings())
            self.update_range_counts()

    def seed_ranger(self, calibration: Calibration, s: Any) -> None:
        """A resumed capture: the samples of slice ``s`` (:class:`reconstruction.core.slicedata.Slice`) turned back
        into readings at the reference setting with their ``calibration``, and their settings from the run record,
        so that auto-ranging predicts the new points' settings from the old neighbours too."""
        if self.ranger is None or len(s) == 0:
            return
        self.ranger.ref_dark = calibration.dark
        ti, to = np.asarray(s.theta_i_deg, dtype=float), np.asarray(s.theta_o_deg, dtype=float)
        k = calibration.scale(to) * np.asarray(calibration.footprint_factor(ti), dtype=float).reshape(-1, 1)
        with np.errstate(all="ignore"):
            mean = calibration.dark.mean + np.asarray(s.values, dtype=float) / k
            std = np.asarray(s.std, dtype=float) * np.sqrt(np.asarray(s.repeats, dtype=float))[:, None] / np.abs(k)
        rec = self.record.auto_range if self.record is not None else None
        ranged: dict[tuple[float, float], int] = {}
        if rec is not None:
            for key, t in rec.points.items():
                a, b = key.split(",")
                ranged[(round(float(a), 6) + 0.0, round(float(b), 6) + 0.0)] = self.ranger.rung_of(
                    t, rec.point_gains.get(key))
        rungs = np.array([ranged.get((round(float(a), 6) + 0.0, round(float(b), 6) + 0.0), 0)
                          for a, b in zip(ti, to, strict=True)], dtype=int)
        ok = np.all(np.isfinite(mean), axis=1) & np.all(np.isfinite(std), axis=1)
        self.ranger.seed(ti[ok], to[ok], mean[ok], std[ok], rungs[ok])

    def _store_dark(self, t: float, rd: Reading, gain: float | None = None) -> None:
        """Keep a dark at a new setting in the run record at once (a resume converts with the same darks)."""
        if self.record is not None and self.record.auto_range is not None:
            self.record.auto_range.store_dark(t, rd, gain)
            self.record.save()

    def update_range_counts(self) -> None:
        rec = self.record.auto_range if self.record is not None else None
        if rec is not None:
            self.result.auto_ranged = len(rec.points)
            self.result.auto_range_settings = rec.settings()

    def _restore(self, m: RestoreSetting) -> None:
        if self.ranger is None:
            return
        self.ranger.restore()
        r = self.result
        if not r.auto_ranged and not r.auto_range_readings:
            return
        settings = "; ".join(f"{k}{'' if 'gain' in k else ' s'}: {v}" for k, v in r.auto_range_settings.items())
        log.info("auto-ranging: %d point(s) of the capture read %s (%s); this run discarded %d reading(s) and "
                 "spent %.3f s of extra integration (dark readings included)", r.auto_ranged,
                 ranged_wording(r.auto_range_settings, self.ranger.t_ref), settings or "none",
                 r.auto_range_readings, r.auto_range_overhead_s)

    # -- calibration and samples ------------------------------------------------------------------------------
    def _calibrate(self, m: Calibrate) -> None:
        self.calibration = m.calibration
        if self.account:  # the calibration's readings and moves are not the first point's motion
            self.t_last = self.dev.clock.now()
        if self.ranger is not None:
            self.ranger.ref_dark = m.calibration.dark
            if m.calibration.gain_factors:
                self.ranger.set_gain_factors(m.calibration.gain_factors)
            rec = self.record.auto_range if self.record is not None else None
            if rec is not None and m.reference_integration_time_s is not None:
                rec.extra["white_reference_integration_time_s"] = m.reference_integration_time_s
        if self.sink is not None:
            self.sink.open(m.calibration, m.reference_integration_time_s if self.ranger is not None else None)

    def _use_reference(self, m: UseReference) -> None:
        if self.calibration is None or self.calibration.reference is None:
            raise DeviceError("a new white reference reading needs a relative calibration to replace")
        cal = replace(self.calibration, reference=m.reading)
        cal.scale(cal.reference_theta_o_deg)  # raises if the reference reads no signal
        for why in reference_doubts(m.reading, cal.dark, previous=self.calibration.reference):
            log.warning("white reference read again, doubtful: %s", why)
        log.info("white reference read again: %s counts (was %s)", np.round(m.reading.mean, 3).tolist()[:8],
                 np.round(self.calibration.reference.mean, 3).tolist()[:8])
        self.calibration = cal

    def _save(self, m: Save) -> tuple[float, float, float, float]:
        ti, to = m.theta_i_deg, m.theta_o_deg
        r = self.result
        if self.calibration is None or not self.convert:  # a dry run: nothing to convert, nothing to write
            if self.account:
                self._account()
            r.samples_new += 1
            if self.bar is not None:
                self.bar.advance()
            return (ti, to, 0.0, 0.0)
        f, fs = self._brdf(m.reading, to, ti)
        rg = m.ranged
        rec = self.record.auto_range if self.record is not None else None
        if rg is not None and rec is not None:
            if rg.ranged:
                log.info("point (%g, %g): auto-ranged to t_int = %g s%s (%d reading(s))", ti, to,
                         rg.integration_time_s, "" if rg.gain is None else f", gain {rg.gain:g}", rg.readings)
            if rec.set_point(ti, to, rg.integration_time_s if rg.ranged else None, rg.gain if rg.ranged else None):
                self.update_range_counts()
                assert self.record is not None
                self.record.save(durable=False)  # before the sample is appended: a point measured again is counted once
        if self.sink is not None:
            self.sink.append(ti, to, f.tolist(), fs.tolist(), m.reading.n if m.repeats <= 0 else m.repeats)
        r.auto_ranged_new += int(rg is not None and rg.ranged)
        r.samples_new += 1  # counted the moment the row is durable: a link lost in the clock read below (TIME?)
        r.samples_total += 1  # still counts it, as it is on disk
        if self.bar is not None:
            self.bar.advance()
        if self.account:
            self._account()
        return (ti, to, float(np.mean(f)), float(np.mean(fs)))

    def _convert(self, m: Convert) -> tuple[float, float, float, float]:
        ti, to = m.theta_i_deg, m.theta_o_deg
        if self.account:
            self._account()
        if self.calibration is None or not self.convert:  # a dry run
            return (ti, to, 0.0, 0.0)
        f, fs = self._brdf(m.reading, to, ti)
        return (ti, to, float(np.mean(f)), float(np.mean(fs)))

    def _brdf(self, reading: Reading, theta_o_deg: float, theta_i_deg: float) -> tuple[Any, Any]:
        """The calibration's f_r of a point's reading; a reading it cannot convert (a ratio reading without the
        monitor's) is the detector's fault, named with the point."""
        assert self.calibration is not None
        try:
            return self.calibration.brdf(reading, theta_o_deg, theta_i_deg)
        except ValueError as e:
            raise DeviceError(f"point ({theta_i_deg:g}, {theta_o_deg:g}): {e}") from None

    def _account(self) -> None:
        """A point saved: its move (since the last point or the calibration), settle and reading times."""
        r = self.result
        t2 = self.dev.clock.now()
        self.t_last = t2
        t0, t1 = self._t_move
        r.motion_s += t1 - t0
        r.settle_s += self.settle_s
        r.read_s += max(t2 - t1 - self.settle_s, 0.0)

    # -- bookkeeping --------------------------------------------------------------------------------------------
    def _announce(self, m: Announce) -> None:
        if self.bar is not None:
            self.bar.announce(m.total, m.done)

    def _tally(self, m: Tally) -> None:
        setattr(self.result, m.name, m.value)
