"""Driver of stepper arms on a GRBL 1.1 controller (an Arduino Uno with a CNC shield), with pyserial.

GRBL's interface (gnea/grbl ``doc/markdown/interface.md``): one line of G-code or a ``$`` command, answered by
``ok`` or ``error:N``; push messages (``ALARM:N``, ``[MSG:...]``, the welcome line ``Grbl 1.1h ['$' for help]``)
at any time; single realtime bytes that are never buffered: ``?`` (a status report ``<Idle|MPos:x,y,z|FS:f,s>``),
``!`` (feed hold), ``~`` (resume) and 0x18 (soft reset). X is the light arm, Y the detector arm, GRBL's "mm" are
degrees of the machine coordinate (:mod:`acquisition.devices.grbl_settings`).

:class:`GrblAxes` (the axes of :class:`acquisition.bench.Bench`, like ``SerialAxes``):

* ``connect``: waits for the welcome line, reads ``$I`` and ``$$`` and compares ``$100/$101``, ``$110/$111``,
  ``$120/$121``, ``$20``, ``$22``, ``$130/$131`` and ``$10`` with the bench file, naming every one that differs,
  **before anything moves**; homes with ``$H`` where the bench has switches. A controller in alarm (after a reset
  in motion or an alarm: GRBL no longer vouches for the position) is refused unless homing is possible or the bench
  file unlocks on purpose (``[motion.grbl].unlock = true`` -> ``$X``).
* ``move``: ``G90 G53 G0 X.. Y..`` (absolute machine coordinates, whatever work offset is set), then ``?`` polled
  until ``Idle`` with ``MPos`` within ``[motion].tolerance_deg`` of the goal: at most 5 Hz (GRBL's interface.md:
  "no more than 5Hz") while the move is expected to run (its duration from the time model), then every
  ``[motion].poll_interval_s`` from its expected end, so that the capture learns of the arrival at once (GRBL
  is then decelerating or idle, and those few reports cost it little). A feed hold nobody here asked for (the
  hold button, ``!`` from another program) is named at the first report that shows it.
* ``stop`` (an abort): feed hold ``!``, wait for the hold to complete (``Hold:0``), then a soft reset (0x18)
  which empties the planner; a reset after a completed hold keeps the position (GRBL raises ``ALARM:3`` only for
  a reset *in* motion, which this driver falls back to if the hold does not complete).
* every ``error:N`` / ``ALARM:N`` becomes one sentence (:func:`~acquisition.devices.grbl_settings.error_text`), and the
  advice after it is the command that works: ``--resume`` when the bench homes (``$H`` first), ``--resume
  --unlock`` when it has no switches (:attr:`GrblAxes.resume_flags`), never a repeat of what just failed.
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass

import serial

from acquisition.devices.driver import Driver, Opening, Port
from acquisition.devices.grbl_settings import (
    AXIS_LETTER,
    LOST_POSITION_ALARMS,
    SETTING_NAMES,
    alarm_text,
    error_text,
    expected_settings,
    machine_deg,
)
from acquisition.devices.lines import next_line
from acquisition.errors import PORT_ERRORS, CommError, DeviceError, HardwareError, PortError, port_reason
from reconstruction.instrument.timing import line_durations
from reconstruction.schema.bench import Axis, GrblTable, MotionTable

log = logging.getLogger("acquisition.grbl")

__all__ = ["GrblAxes", "GrblError", "GrblStatus", "parse_status"]

_STATUS = re.compile(r"^<([A-Za-z]+)(?::(\d))?\|(.*)>$")
_ALARM = re.compile(r"^ALARM:(\d{1,3})$")
_ERROR = re.compile(r"^error:(\d{1,3})$")
_SETTING = re.compile(r"^\$(\d{1,3})=([-+0-9.]+)$")
_WELCOME = "Grbl "
RESET = b"\x18"
#: Relative tolerance of a ``$`` setting against the bench file (GRBL prints 3 decimals).
SETTING_RTOL = 1e-3
#: Status reports while a move is expected to run: at most 5 Hz (GRBL's interface.md).
MOVING_POLL_S = 0.2
#: GRBL's homing alarms: ``$H`` failed, so "home them" is not the advice.
HOMING_ALARMS = frozenset({6, 7, 8, 9, 10})


class GrblError(DeviceError):
    """GRBL answered ``error:N`` (``code``) to a line."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


class GrblAlarm(DeviceError):
    """GRBL pushed ``ALARM:N`` (``code``) while a line waited for its answer (after a limit alarm GRBL answers
    nothing until it is reset)."""

    def __init__(self, message: str, code: int) -> None:
        super().__init__(message)
        self.code = code


@dataclass(frozen=True)
class GrblStatus:
    """A status report: ``state`` (Idle, Run, Hold, Jog, Alarm, Door, Check, Home, Sleep), ``sub`` (Hold:0
    complete / Hold:1 decelerating; None without), ``mpos`` (machine position per axis, GRBL "mm" = degrees)."""

    state: str
    sub: int | None
    mpos: tuple[float, ...]
    raw: str


def parse_status(line: str) -> GrblStatus | None:
    """A ``<...>`` status report, or None if ``line`` is not a complete one with an ``MPos`` field."""
    m = _STATUS.match(line)
    if not m:
        return None
    fields = dict(f.split(":", 1) for f in m.group(3).split("|") if ":" in f)
    if "MPos" not in fields:
        return None
    try:
        mpos = tuple(float(x) for x in fields["MPos"].split(","))
    except ValueError:
        return None
    return GrblStatus(m.group(1), int(m.group(2)) if m.group(2) else None, mpos, line)


class GrblAxes:
    """The light (X) and detector (Y) arms on GRBL; angles in degrees, times in seconds."""

    def __init__(self, port: str, axes: Mapping[str, Axis], motion: MotionTable,
                 serial_factory: Callable[..., serial.Serial] = serial.Serial) -> None:
        self.port = port
        self.axes = {n: axes[n] for n in AXIS_LETTER}
        self.motion = motion
        self.grbl: GrblTable = motion.grbl if motion.grbl is not None else GrblTable()
        self.name = "GRBL"
        self.goal: dict[str, float] = {}
        self.cancel: Callable[[], None] = lambda: None
        self.trusted = False  # GRBL vouches for the position (homed, or never reset in motion / alarmed)
        self.alarm = 0  # the last ALARM:N seen (0: none since the last unlock or homing)
        self.dead = False
        self.settings: dict[int, float] = {}
        self.version = ""
        self.options = ""  # $I's [OPT:...] line: our build (firmware/grbl) has 'H' (single-axis homing) in it
        self._last: GrblStatus | None = None
        self._holding = False  # a feed hold this driver asked for (stop)
        self._buf = bytearray()
        try:
            self.ser = serial_factory(port, self.grbl.baudrate, timeout=0.02, write_timeout=2.0)
        except (*PORT_ERRORS, ValueError) as e:
            why = port_reason(e)
            raise PortError(f"GRBL: cannot open {port!r}: {why}", port, why) from None

    # -- bytes and lines -------------------------------------------------------------------------------------------
    def _write(self, data: bytes) -> None:
        try:
            self.ser.write(data)
        except PORT_ERRORS as e:
            self.dead = True
            raise CommError(f"GRBL on {self.port}: cannot send {data[:40]!r} ({e}); is the controller still "
                            "connected?") from None

    def _readline(self, deadline: float) -> str | None:
        """The next non-empty line (push messages noted on the way: ALARM, welcome), or None at the deadline."""
        try:
            raw = next_line(self.ser, self._buf, deadline)
        except PORT_ERRORS as e:
            self.dead = True
            raise CommError(f"GRBL on {self.port}: port failed ({e}); is the controller still "
                            "connected?") from None
        if raw is None:
            return None
        line = raw.decode("ascii", errors="replace").strip()
        self._note(line)
        return line

    def _note(self, line: str) -> None:
        m = _ALARM.match(line)
        if m:
            self.alarm = int(m.group(1))
            if self.alarm in LOST_POSITION_ALARMS:
                self.trusted = False
            log.warning("GRBL on %s: %s", self.port, alarm_text(self.alarm))
        elif line.startswith(_WELCOME):
            log.info("GRBL on %s: %s", self.port, line)
        elif line.startswith("[MSG:"):
            log.info("GRBL on %s: %s", self.port, line)

    def command(self, line: str, timeout_s: float | None = None) -> list[str]:
        """Send one line and return the lines before its ``ok``. ``error:N`` raises :class:`GrblError` (one
        sentence); no answer within ``timeout_s`` (default ``[motion].timeout_s``) raises :class:`CommError`."""
        self._write((line + "\n").encode("ascii"))
        deadline = time.monotonic() + (self.motion.timeout_s if timeout_s is None else timeout_s)
        lines: list[str] = []
        while True:
            got = self._readline(deadline)
            if got is None:
                raise CommError(f"GRBL on {self.port}: no answer to {line!r} within "
                                f"{self.motion.timeout_s if timeout_s is None else timeout_s:g} s")
            if got == "ok":
                return lines
            a = _ALARM.match(got)
            if a:
                code = int(a.group(1))
                raise GrblAlarm(f"GRBL on {self.port}: {line!r} ended in {alarm_text(code)}", code)
            m = _ERROR.match(got)
            if m:
                code = int(m.group(1))
                raise GrblError(f"GRBL on {self.port}: {line!r} refused: {error_text(code)}", code)
            lines.append(got)

    def status(self) -> GrblStatus:
        """A fresh status report (``?``), asked up to ``[motion].retries`` + 1 times. An ``ALARM:N`` pushed
        meanwhile is returned as state ``Alarm`` at the last known position: after a limit alarm GRBL sends no
        report until it is reset."""
        for _ in range(self.motion.retries + 1):
            self._write(b"?")
            deadline = time.monotonic() + 1.0
            while True:
                line = self._readline(deadline)
                if line is None:
                    break
                if _ALARM.match(line):
                    return GrblStatus("Alarm", None, self._last.mpos if self._last else (0.0, 0.0, 0.0), line)
                st = parse_status(line)
                if st is not None:
                    self._last = st
                    return st
        raise CommError(f"GRBL on {self.port}: no status report (?) after {self.motion.retries + 1} attempts; "
                        "is this a GRBL 1.1 controller at the configured baud rate?")

    def _drain(self, wait_s: float) -> list[str]:
        """Lines that arrive within ``wait_s`` (the welcome after a reset, stale output)."""
        out = []
        deadline = time.monotonic() + wait_s
        while (line := self._readline(deadline)) is not None:
            out.append(line)
        return out

    def _await_reset_request(self, wait_s: float) -> None:
        deadline = time.monotonic() + wait_s
        while (line := self._readline(deadline)) is not None:
            if line.startswith("[MSG:Reset to continue"):
                return

    def _await_welcome(self, wait_s: float) -> bool:
        deadline = time.monotonic() + wait_s
        while (line := self._readline(deadline)) is not None:
            if line.startswith(_WELCOME):
                return True
        return False

    # -- connection ------------------------------------------------------------------------------------------------
    def connect(self) -> None:
        """Check the controller and its settings against the bench file (nothing moves before), then home or
        refuse an untrusted position (see the module)."""
        self._await_welcome(self.grbl.boot_s)
        self._drain(0.05)
        if not self._answers_status():
            # after a limit alarm GRBL waits for a reset ([MSG:Reset to continue]) and answers nothing, not even
            # '?'; it is not moving, so the reset loses nothing (it stays in its alarm state)
            log.info("GRBL on %s: no status report; resetting it (a limit alarm waits for a reset)", self.port)
            self._write(RESET)
            self._await_welcome(3.0)
            self._drain(0.05)
        self.version = self._sync()
        if not self.version.startswith("[VER:1.1"):
            log.warning("GRBL on %s: %s; this driver is written for GRBL 1.1", self.port,
                        self.version or "no [VER:] line")
        st = self.status()
        if st.state in ("Run", "Jog", "Hold", "Home"):
            raise DeviceError(f"GRBL on {self.port}: the controller is busy ({st.state}); wait for it, or reset it, "
                              "before starting a capture")
        self.check_settings()
        self._gain_trust(st)
        self.command("G21 G90")
        log.info("GRBL on %s ready: %s, arms at %s", self.port, self.version, self.positions())

    def _answers_status(self) -> bool:
        self._write(b"?")
        deadline = time.monotonic() + 1.5
        while (line := self._readline(deadline)) is not None:
            st = parse_status(line)
            if st is not None:
                self._last = st
                return True
        return False

    def _sync(self) -> str:
        """``$I`` until its ``[VER:...]`` line and the ``ok`` after it: an ``ok`` still owed to a line someone sent
        before the port was ours is skipped, so every later answer belongs to this driver's line. Returns the
        ``[VER:...]`` line ("" if GRBL answers without one)."""
        for _ in range(2):
            self._write(b"$I\n")
            deadline = time.monotonic() + 3.0
            version = ""
            while (line := self._readline(deadline)) is not None:
                if line.startswith("[VER:"):
                    version = line
                elif line.startswith("[OPT:"):
                    self.options = line
                elif line == "ok" and version:
                    return version
                elif _ERROR.match(line) and not version:
                    return ""
        raise CommError(f"GRBL on {self.port}: no answer to $I; is GRBL 1.1 on this port at "
                        f"{self.grbl.baudrate} baud?")

    def read_settings(self) -> dict[int, float]:
        """``$$``: every ``$N=value`` setting."""
        out = {}
        for ln in self.command("$$", 5.0):
            m = _SETTING.match(ln)
            if m:
                out[int(m.group(1))] = float(m.group(2))
        self.settings = out
        return out

    def setting_differences(self) -> list[tuple[int, str]]:
        """(setting number, one sentence) per checked setting that differs from the bench file (empty: all
        agree)."""
        have = self.read_settings()
        want = expected_settings(self.axes, self.motion)
        keys = {100: "[axes.light].units_per_deg", 101: "[axes.detector].units_per_deg",
                110: "60 x [motion].velocity_deg_s", 111: "60 x [motion].velocity_deg_s",
                120: "[motion].acceleration_deg_s2", 121: "[motion].acceleration_deg_s2",
                20: "[motion.grbl].soft_limits", 22: "[motion.grbl].homing",
                130: "the light arm's travel", 131: "the detector arm's travel"}
        out = []
        for n, v in sorted(want.items()):
            got = have.get(n)
            if n in (130, 131):  # GRBL's travel must hold the arms' range (a larger one protects less)
                ok = got is not None and got >= v - max(1e-3, SETTING_RTOL * v)
                need = f"at least {v:.3f}"
            else:
                ok = got is not None and abs(got - v) <= max(1e-3, SETTING_RTOL * abs(v))
                need = f"{v:.3f}" if n >= 100 else f"{v:.0f}"
            if not ok:
                shown = "missing" if got is None else f"{got:g}"
                out.append((n, f"${n} ({SETTING_NAMES[n]}) is {shown}, the bench file needs {need} ({keys[n]})"))
        mask = have.get(10)
        if mask is not None and not int(mask) & 1:
            out.append((10, f"$10 ({SETTING_NAMES[10]}) is {mask:g}: set bit 0 ($10=1) so that status reports give "
                            "the machine position"))
        return out

    def check_settings(self) -> None:
        """Raise :class:`DeviceError` naming every setting that differs (with the lines that fix them)."""
        diffs = self.setting_differences()
        if diffs:
            want = {**expected_settings(self.axes, self.motion), 10: 1.0}
            fix = " ".join(f"${n}={want[n]:.3f}".rstrip("0").rstrip(".") for n, _ in diffs)
            raise DeviceError(f"GRBL on {self.port}: its settings differ from the bench file: "
                              + "; ".join(text for _, text in diffs)
                              + f". Nothing was moved. Send GRBL the bench's values ({fix}) or fix the bench file")

    def _gain_trust(self, st: GrblStatus) -> None:
        """Home, unlock on purpose, or refuse: after this the position is trusted or DeviceError is raised."""
        g = self.grbl
        if g.homing:
            self.home()
            return
        if st.state == "Alarm" or st.state == "Sleep":
            why = alarm_text(self.alarm) if self.alarm else "GRBL is in its alarm state (a reset in motion, an " \
                                                             "alarm, or homing enabled at power-up)"
            if not g.unlock:
                raise DeviceError(f"GRBL on {self.port}: {why}; the arms' position is not trusted, so nothing "
                                  "moves: home them ([motion.grbl].homing = true, needs switches) or check they are "
                                  "where GRBL believes and unlock on purpose (gonio-capture --unlock, or "
                                  "[motion.grbl].unlock = true; $X)")
            self.unlock()
            return
        self.trusted = True

    def unlock(self) -> None:
        """``$X``: leave the alarm state on purpose (GRBL's position is taken as it is)."""
        log.warning("GRBL on %s: unlocking ($X) on purpose: the position GRBL reports is taken as true", self.port)
        self.command("$X", 2.0)
        self.alarm = 0
        self.trusted = True

    @property
    def stock_build(self) -> bool:
        """``$I``'s options lack 'H' (``HOMING_SINGLE_AXIS_COMMANDS``, set by this project's build): most likely the
        release hex, whose homing cycle moves Z first."""
        return bool(self.options) and "H" not in self.options.split(":", 1)[-1].split(",", 1)[0]

    def _homing_failed(self, why: str) -> DeviceError:
        advice = ("check each arm's switch and its wiring (a pressed switch shows in the status report's Pn: field; "
                  "$HX and $HY home one arm), $130/$131 and $27; once homing works, resume; or move the arms where "
                  "GRBL believes them and resume with --unlock")
        if self.stock_build and self.alarm == 9:
            advice = ("this GRBL looks like the stock build ($I lists no 'H' option), whose homing cycle moves Z first "
                      "and finds no Z switch on this bench: flash the project's build (make -C firmware/grbl, "
                      "docs/build-a-bench.md), then resume")
        self.trusted = False
        return DeviceError(f"GRBL on {self.port}: {why}; homing failed, the arms' position is not known: {advice}")

    def home(self) -> None:
        """``$H``: GRBL's homing cycle (its ``ok`` comes once the arms are pulled off their switches)."""
        log.info("GRBL on %s: homing ($H)", self.port)
        try:
            self.command("$H", self.motion.timeout_s * 3)
        except GrblAlarm as e:
            self._await_welcome(2.0)  # a failed homing resets GRBL: its welcome follows
            raise self._homing_failed(alarm_text(e.code)) from None
        except GrblError as e:
            raise DeviceError(f"{e}; homing did not run" + (f" ({alarm_text(self.alarm)})" if self.alarm else "")) \
                from None
        except CommError:
            raise self._homing_failed(f"$H gave no answer within {self.motion.timeout_s * 3:g} s"
                                      + (f" ({alarm_text(self.alarm)})" if self.alarm else "")) from None
        st = self.status()
        if st.state != "Idle":
            raise self._homing_failed(f"$H ended in state {st.state}"
                                      + (f" ({alarm_text(self.alarm)})" if self.alarm else ""))
        self.alarm = 0
        self.trusted = True
        log.info("GRBL on %s: homed; arms pulled off their switches at MPos %s", self.port,
                 ",".join(f"{v:.3f}" for v in st.mpos[:2]))

    @property
    def resume_flags(self) -> str:
        """What ``gonio-capture --resume`` needs added to work after this driver stopped: ``" --unlock"`` when the
        position is not trusted and the bench cannot home (no switches), else nothing (homing runs ``$H``)."""
        return "" if self.trusted or self.grbl.homing or self.grbl.unlock else " --unlock"

    # -- positions and moves ---------------------------------------------------------------------------------------
    def _deg(self, st: GrblStatus) -> dict[str, float]:
        out = {}
        for i, (name, ax) in enumerate(self.axes.items()):
            out[name] = ax.units_to_deg(st.mpos[i] * ax.units_per_deg)
        return out

    def positions(self) -> dict[str, float]:
        """Present arm angles (deg) from GRBL's machine position."""
        return self._deg(self.status())

    def _send(self, goals: Mapping[str, float]) -> None:
        words = " ".join(f"{AXIS_LETTER[n]}{machine_deg(self.axes[n], d):.4f}" for n, d in goals.items())
        try:
            self.command(f"G90 G53 G0 {words}", 5.0)
        except GrblAlarm as e:
            self._alarm_stop(e.code)
        except GrblError as e:
            if self.alarm:
                self._alarm_stop(self.alarm)
            raise DeviceError(str(e)) from None

    def _expected_s(self, goals: Mapping[str, float]) -> float:
        """The move's duration from the time model (s): both arms on one line at $110/$120 (0 if unknown)."""
        if self._last is None:
            return 0.0
        here = self._deg(self._last)
        d = [machine_deg(self.axes[n], goals.get(n, here[n])) - machine_deg(self.axes[n], here[n]) for n in AXIS_LETTER]
        v, a = self.motion.velocity_deg_s, self.motion.acceleration_deg_s2
        if v <= 0 or a <= 0:
            return 0.0
        return float(line_durations(d[0], d[1], (v, v), (a, a)))

    def move(self, goals: Mapping[str, float], check_cancel: bool = True) -> None:
        """Move the named arms to ``goals`` (deg) at once and wait until ``Idle`` and in position."""
        if not self.trusted:
            raise DeviceError(f"GRBL on {self.port}: the arms' position is not trusted since "
                              + (alarm_text(self.alarm) if self.alarm else "a reset or an alarm")
                              + "; home them or unlock on purpose (gonio-capture --unlock) before moving")
        self.goal.update(goals)
        expected = self._expected_s(goals)
        self._send(goals)
        self._wait(dict(goals), check_cancel, expected)

    def _off(self, st: GrblStatus, goals: Mapping[str, float]) -> dict[str, float]:
        deg = self._deg(st)
        return {n: deg[n] for n, g in goals.items() if abs(deg[n] - g) > self.motion.tolerance_deg}

    def _wait(self, goals: dict[str, float], check_cancel: bool, expected_s: float = 0.0) -> None:
        t0 = time.monotonic()
        t_end = t0 + self.motion.timeout_s
        resends = idle_off = 0
        while True:
            if check_cancel:
                self.cancel()
            st = self.status()
            if st.state == "Alarm" or self.alarm:
                self._alarm_stop(self.alarm)
            if st.state == "Hold" and not self._holding:
                self._outside_hold(st)
            if st.state == "Door":
                self.stop()
                raise HardwareError(f"GRBL on {self.port}: the safety door input is active; the arms were stopped")
            if st.state == "Idle":
                off = self._off(st, goals)
                if not off:
                    return
                idle_off += 1  # idle before the planner started the block: look again before deciding
                if idle_off >= 3:
                    if resends >= self.motion.retries:
                        name, deg = next(iter(off.items()))
                        raise DeviceError(f"GRBL on {self.port}: the {name} arm stopped at {deg:.3f} deg, not at its "
                                          f"goal {goals[name]:.3f} deg (tolerance {self.motion.tolerance_deg:g}) "
                                          f"after {resends} re-sends")
                    resends += 1
                    idle_off = 0
                    log.warning("GRBL on %s: idle but not in position (%s); re-sending the move", self.port, off)
                    self._send(goals)
            else:
                idle_off = 0
            if time.monotonic() > t_end:
                self.stop()
                raise DeviceError(f"GRBL on {self.port}: the arms still move after {self.motion.timeout_s:g} s "
                                  f"(state {st.state}, goals {goals}); stopped")
            time.sleep(self._poll_s(time.monotonic() - t0, expected_s))

    def _poll_s(self, elapsed: float, expected_s: float) -> float:
        """The wait before the next status report: at most 5 Hz until the move's expected end, then
        ``[motion].poll_interval_s`` (see the module)."""
        fast = self.motion.poll_interval_s
        left = expected_s - elapsed
        if left <= 0:
            return fast
        return max(fast, min(MOVING_POLL_S, left))

    def _outside_hold(self, st: GrblStatus) -> None:
        """GRBL reports a feed hold nobody here asked for (the hold button, ``!`` from another program): stop
        cleanly (the hold keeps the position) and raise :class:`HardwareError` naming it."""
        where = self._deg(st)
        self.stop()
        raise HardwareError(f"GRBL on {self.port}: a feed hold came from outside gonio-capture ({st.state}:"
                            f"{st.sub}: the hold button, or '!' from another program on this port); the arms stopped "
                            "at " + ", ".join(f"{n} {d:.2f} deg" for n, d in where.items())
                            + " and the capture stopped; the position is kept")

    def _alarm_stop(self, code: int) -> None:
        """An alarm mid-move: GRBL has stopped the steppers itself; reset a limit alarm (GRBL answers nothing
        until then), recover a soft-limit alarm (position kept), raise :class:`HardwareError` with one sentence
        whose advice is the command that works."""
        if code in (1, 2):
            try:  # GRBL asks for a reset ([MSG:Reset to continue]); after ALARM:2 the position is kept, $X is safe
                self._await_reset_request(3.0)  # a reset before it is lost: GRBL clears it, then waits for one
                self._write(RESET)
                self._await_welcome(3.0)
                if code == 2:
                    self.command("$X", 2.0)
                    self.alarm = 0
                    self.trusted = True
            except Exception as e:  # noqa: BLE001 - best effort; the message below stands
                log.warning("GRBL on %s: reset after %s failed: %s", self.port, alarm_text(code), e)
        if self.trusted:
            advice = ""
        elif self.grbl.homing:
            advice = "; resume with --resume: the arms are homed ($H) first"
        else:
            advice = ("; check the arms are where GRBL believes them (or move them there), then resume with "
                      "--resume --unlock ($X on purpose)")
        raise HardwareError(f"GRBL on {self.port}: " + (alarm_text(code) if code else "alarm state") +
                            "; the capture stopped" + advice)

    def stop(self) -> None:
        """Abort: feed hold (``!``), wait for the hold to complete, then soft reset (0x18) to empty the planner.
        Best effort, never raises."""
        if self.dead:
            log.error("GRBL on %s is gone: cannot stop the arms; cut the motor power", self.port)
            return
        try:
            self._holding = True
            self._write(b"!")
            deadline = time.monotonic() + max(2.0, self.motion.timeout_s / 4)
            while time.monotonic() < deadline:
                st = self.status()
                if st.state == "Idle" or st.state == "Alarm" or (st.state == "Hold" and st.sub == 0):
                    break
                time.sleep(0.01)
            else:
                log.warning("GRBL on %s: the feed hold did not complete; resetting in motion", self.port)
            self._write(RESET)
            self._await_welcome(2.0)
            self._drain(0.02)
            st = self.status()
            if st.state == "Alarm":
                self.trusted = False
                log.error("GRBL on %s: %s", self.port, alarm_text(self.alarm) if self.alarm else "alarm after reset")
        except Exception as e:  # noqa: BLE001 - best effort
            log.warning("GRBL on %s: stop failed: %s", self.port, e)
        finally:
            self._holding = False

    def release(self) -> None:
        """GRBL keeps or drops the motor current by its ``$1`` idle delay: nothing to send."""

    def healthy(self) -> bool:
        """The port answers and GRBL vouches for the position (parking is safe; a move still running, cut short
        by Ctrl-C in the driver's wait, is finished first by GRBL's planner)."""
        if self.dead or not self.trusted:
            return False
        try:
            return self.status().state not in ("Alarm", "Door", "Sleep")
        except Exception:  # noqa: BLE001
            return False

    def close(self) -> None:
        try:
            self.ser.close()
        except Exception:  # pragma: no cover - closing a vanished port
            pass


def _open(o: Opening) -> GrblAxes:
    """The arms on the GRBL controller of ``o``."""
    return GrblAxes(o.ports["grbl"], o.cfg.axes, o.cfg.motion)


#: ``[motion].type = "grbl"``: stepper arms on a GRBL 1.1 controller, ``[motion.grbl]``
#: (:mod:`acquisition.devices.registry`).
DRIVER = Driver("grbl", "motion", GrblTable,
                (Port("grbl", "[motion.grbl].port", "[motion.grbl].baudrate", "GRBL controller (the arms)"),), _open)
