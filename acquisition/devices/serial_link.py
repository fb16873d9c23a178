"""Drivers for the serial text-protocol controller (docs/serial-protocol.md), with pyserial.

:class:`SerialLink` sends one command line and reads its reply: data lines, then exactly one final line ``ok`` or
``error:N``. Timeouts, unparsable or inconsistent replies are retried a bounded number of times (the input is
drained first, so a late reply cannot be taken for the next one); then a :class:`CommError` names the port and
the command. ``error:N`` replies raise :class:`ControllerError` (not retried: the controller understood).

:class:`SerialDetector` reads the detector (``READ``/``DARK``/``DETECTOR?``/``INT``/``SAMPLE``), :class:`SerialAxes`
drives stepper axes (``MOVE``, then polls ``STATUS?`` until idle and in position; alarms stop the capture).
"""

from __future__ import annotations

import logging
import re
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
import serial

from acquisition.calibration import Reading, pool
from acquisition.devices.driver import Driver, Opening, Port
from acquisition.devices.lines import next_line
from acquisition.errors import PORT_ERRORS, CommError, DeviceError, HardwareError, PortError, port_reason
from reconstruction.schema.bench import Axis, DetectorTable, MotionTable

log = logging.getLogger("acquisition.serial")

__all__ = ["SerialLink", "ControllerError", "SerialDetector", "SerialAxes", "Reply", "probe_port"]


def probe_port(port: str, baudrate: int) -> str | None:
    """Whether ``port`` can be opened at ``baudrate``: None if it can (it is closed again at once; nothing is
    sent), else why not (:func:`acquisition.errors.port_reason`)."""
    if not port:
        return "no port given"
    try:
        serial.Serial(port, baudrate, timeout=0.02).close()
    except (*PORT_ERRORS, ValueError) as e:
        return port_reason(e)
    return None

ERROR_TEXT = {
    1: "unknown command",
    2: "bad or missing argument",
    3: "target outside the axis soft limits",
    4: "line too long",
    8: "not homed",
    9: "locked by an alarm (RESET needed)",
    10: "not available on this bench",
    11: "busy: axes are moving",
    20: "collision: arms closer than the minimum separation",
    21: "axis stalled",
}
ALARM_TEXT = {20: "move refused: the arms would collide", 21: "an axis stalled"}

_FINAL = re.compile(r"^(ok|error:(\d{1,3}))$")
_ALARM = re.compile(r"^ALARM:(\d{1,3})$")
_FIELD = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*=[^\s=]*$")
_WORD = re.compile(r"^[A-Za-z][A-Za-z0-9_?]*$")
#: data-line tag expected for a command (by its first word)
_TAGS = {"ID?": "ID", "STATUS?": "STATUS", "?": "STATUS", "TIME?": "TIME", "READ": "READ", "DARK": "DARK",
         "HELP": "HELP", "DETECTOR?": "DETECTOR", "INT?": "INT", "GAIN?": "GAIN", "SAMPLE?": "SAMPLE",
         "SETTLE?": "SETTLE"}


class ControllerError(DeviceError):
    """The controller answered ``error:N`` (``code``), possibly after ``ALARM:N`` (``alarm``)."""

    def __init__(self, message: str, code: int, alarm: int | None = None) -> None:
        super().__init__(message)
        self.code = code
        self.alarm = alarm


@dataclass
class Reply:
    """A complete reply: the data fields of the expected data line (``key -> value`` strings) and all lines."""

    fields: dict[str, str]
    lines: list[str]
    words: tuple[str, ...] = ()


class _Corrupt(Exception):
    pass


class SerialLink:
    """One text-protocol controller on a serial port. ``timeout_s``: reply deadline on top of the expected
    duration of the command; ``retries``: extra attempts after a timeout or a corrupt reply."""

    def __init__(self, port: str, baudrate: int = 115200, timeout_s: float = 1.0, retries: int = 3,
                 name: str = "serial controller") -> None:
        self.port = port
        self.name = name
        self.timeout_s = timeout_s
        self.retries = retries
        self.stats = {"commands": 0, "retries": 0, "timeouts": 0, "corrupt": 0}
        self._buf = bytearray()
        self.dead = False
        #: a start-up banner (``BOOT name=...``, docs/serial-protocol.md) means the board restarted and lost its
        #: settings: once they are set (:meth:`SerialDetector.connect`) that stops the command; before, it is
        #: skipped (an Arduino restarts when its port is opened)
        self.boot_is_fatal = False
        try:
            self.ser = serial.Serial(port, baudrate, timeout=0.02, write_timeout=2.0)
        except (*PORT_ERRORS, ValueError) as e:
            why = port_reason(e)
            raise PortError(f"{name}: cannot open {port!r}: {why}", port, why) from None
        self.ser.reset_input_buffer()

    def close(self) -> None:
        try:
            self.ser.close()
        except Exception:  # pragma: no cover - closing a vanished port
            pass

    def _readline(self, deadline: float) -> str | None:
        """Next line (stripped), or None at the deadline. Raises _Corrupt for a non-ASCII line."""
        try:
            raw = next_line(self.ser, self._buf, deadline)
        except PORT_ERRORS as e:
            self.dead = True
            raise CommError(f"{self.name} on {self.port}: port failed ({e}); is the controller "
                            "still connected?") from None
        if raw is None:
            return None
        if any(c < 0x20 or c > 0x7E for c in raw):
            raise _Corrupt(f"non-ASCII bytes in line {raw!r}")
        return raw.decode("ascii").strip()

    def _drain(self) -> None:
        time.sleep(0.005)
        try:
            self.ser.reset_input_buffer()
            while self.ser.in_waiting:
                self.ser.read(self.ser.in_waiting)
        except PORT_ERRORS:
            pass
        self._buf.clear()

    def _collect(self, cmd: str, tag: str | None, deadline: float) -> Reply:
        lines: list[str] = []
        data: dict[str, str] | None = None
        words: list[str] = []
        alarm: int | None = None
        while True:
            line = self._readline(deadline)
            if line is None:
                if lines:
                    raise _Corrupt(f"incomplete reply {lines!r}")
                raise TimeoutError
            if "BOOT name=" in line:
                self._boot(cmd, line)
                continue
            lines.append(line)
            m = _FINAL.match(line)
            if m:
                if m.group(2) is not None:
                    code = int(m.group(2))
                    if code not in ERROR_TEXT:
                        raise _Corrupt(f"unknown error code in {line!r}")
                    text = ERROR_TEXT[code]
                    if alarm is not None:
                        text += f" (ALARM:{alarm}: {ALARM_TEXT.get(alarm, 'alarm')})"
                    raise ControllerError(f"{self.name} on {self.port}: {cmd!r} failed: error:{code} {text}",
                                          code, alarm)
                if tag is not None and data is None:
                    raise _Corrupt(f"reply to {cmd!r} lacks its {tag} line: {lines!r}")
                return Reply(data or {}, lines, tuple(words))
            m = _ALARM.match(line)
            if m:
                alarm = int(m.group(1))
                continue
            if tag is not None and data is None and line.startswith(tag + " "):
                parts = line.split()[1:]
                if all(_FIELD.match(p) or _WORD.match(p) for p in parts):
                    data = dict(p.split("=", 1) for p in parts if "=" in p)
                    words = [p for p in parts if "=" not in p]
                    continue
            raise _Corrupt(f"unexpected line {line!r} in the reply to {cmd!r}")

    def _boot(self, cmd: str, line: str) -> None:
        banner = line[line.index("BOOT name="):]
        if not self.boot_is_fatal:
            log.info("%s on %s: the board started (%s)", self.name, self.port, banner)
            return
        raise DeviceError(f"{self.name} on {self.port}: the board restarted during {cmd!r} ({banner}); its settings "
                          "(integration time, gain) were lost: resume the capture")

    def command(self, cmd: str, expect_s: float = 0.0, check: Callable[[Reply], None] | None = None,
                busy_ok: bool = False) -> Reply:
        """Send ``cmd`` and return its reply. ``expect_s``: how long the command itself takes (s, wall), added
        to the deadline; ``check(reply)`` may raise ValueError to reject an inconsistent reply (retried);
        ``busy_ok``: on a retry, ``error:11`` (busy) means that an earlier attempt was executed."""
        word = cmd.split()[0].upper()
        tag = _TAGS.get(word)
        problem = ""
        self.stats["commands"] += 1
        for attempt in range(self.retries + 1):
            if attempt:
                self.stats["retries"] += 1
                log.info("%s: retrying %r (attempt %d of %d): %s", self.name, cmd, attempt + 1,
                         self.retries + 1, problem)
                self._drain()
            try:
                self.ser.write((cmd + "\n").encode("ascii"))
            except PORT_ERRORS as e:
                self.dead = True
                raise CommError(f"{self.name} on {self.port}: cannot send {cmd!r} ({e}); is the controller "
                                "still connected?") from None
            deadline = time.monotonic() + self.timeout_s + expect_s
            try:
                reply = self._collect(cmd, tag, deadline)
                if check is not None:
                    check(reply)
                return reply
            except TimeoutError:
                self.stats["timeouts"] += 1
                problem = f"no reply within {self.timeout_s + expect_s:.2f} s"
            except (_Corrupt, ValueError, KeyError) as e:
                self.stats["corrupt"] += 1
                problem = f"corrupt reply: {e}"
            except ControllerError as e:
                if busy_ok and attempt and e.code == 11:
                    return Reply({}, ["error:11"])
                raise
        raise CommError(f"{self.name} on {self.port}: no valid reply to {cmd!r} after {self.retries + 1} "
                        f"attempts (last: {problem})")

    def fields(self, cmd: str, **kw) -> dict[str, str]:
        return self.command(cmd, **kw).fields


#: Relative tolerance between the integration time set and the one a reply reports (printed with 6 digits).
_T_INT_RTOL = 1e-4


def _floats(text: str) -> np.ndarray:
    vals = np.array([float(x) for x in text.split(",")], dtype=float)
    if not np.all(np.isfinite(vals)):
        raise ValueError(f"non-finite number in {text!r}")
    return vals


class SerialDetector:
    """Photodiode or spectrometer behind the serial controller. ``channels`` are slice column names
    (``["value"]`` or ``["380nm", ...]``), ``wavelengths_nm`` the spectrometer grid (None for a photodiode)."""

    def __init__(self, link: SerialLink, expected_type: str, integration_time_s: float,
                 saturation: float, gains: tuple[float, ...] | None = None, start_gain: float | None = None) -> None:
        self.link = link
        self.gains = gains
        self.start_gain = start_gain if start_gain is not None else (min(gains) if gains else None)
        self.gain: float | None = None
        self.expected_type = expected_type
        self.integration_time_s = integration_time_s
        self.saturation = saturation
        self._config_saturation = saturation
        self.dc_amplifier = False  # DETECTOR? says amplifier=dc (the board): auto-ranging over its gains only
        self.summing = False  # DETECTOR? lists conversions= (the board): its saturation grows with INT
        self.chop = False  # [detector].chop: CHOP ON at connect
        self.type = expected_type
        self.wavelengths_nm: np.ndarray | None = None
        self.n_channels = 1
        self.has_time = False
        self.has_dwell = False
        self.has_sample_changer = True
        self.manual_swap: Callable[[str], None] | None = None

    @property
    def channels(self) -> list[str]:
        if self.wavelengths_nm is None:
            return ["value"]
        return [f"{w:g}nm" for w in self.wavelengths_nm]

    def connect(self) -> None:
        """Identify the controller and detector, set the integration time, put the sample in place."""
        cmds = {w.upper() for w in self.link.command("HELP").words}
        self.has_time = "TIME?" in cmds
        self.has_dwell = "DWELL" in cmds
        self.has_sample_changer = "SAMPLE" in cmds
        if self.chop:  # a controller without CHOP answers error:1, named
            self.link.command("CHOP ON")
        d = self.link.fields("DETECTOR?", check=_check_detector)
        self.type = d["type"]
        if self.type != self.expected_type:
            raise DeviceError(f"{self.link.name} on {self.link.port}: the detector is a {self.type}, but the "
                              f"config says [detector].type = {self.expected_type!r}")
        self.n_channels = int(d["channels"])
        if self.type == "spectrometer":
            self.wavelengths_nm = _floats(d["wavelengths"])
            if self.wavelengths_nm.size != self.n_channels:
                raise DeviceError(f"{self.link.name}: DETECTOR? lists {self.wavelengths_nm.size} wavelengths for "
                                  f"{self.n_channels} channels")
        self.saturation = min(self._config_saturation, float(d["saturation"]))
        self.dc_amplifier, self.summing = d.get("amplifier") == "dc", "conversions" in d
        if abs(float(d["t_int"]) - self.integration_time_s) > 1e-9 * max(1.0, self.integration_time_s):
            self.set_integration_time(self.integration_time_s)  # a board may round it (INT?): believed
        if self.gains:
            if "gains" in d:  # the amplifier lists its gains: the config's must be among them
                have = _floats(d["gains"])
                missing = [g for g in self.gains if not np.any(np.abs(have - g) <= 1e-6 * g)]
                if missing:
                    listed = ", ".join(f"{g:g}" for g in have)
                    raise DeviceError(f"{self.link.name}: the amplifier has the gains {listed}"
                                      f"; [detector].gains lists {', '.join(f'{g:g}' for g in missing)}, which it "
                                      "has not")
            self.set_gain(self.start_gain)  # auto-ranging's reference setting (the highest), else the lowest
        self.set_sample("TARGET")
        self.link.boot_is_fatal = True

    def _set_and_read_back(self, command: str, query: str, field: str, value: float) -> float:
        """Send ``command value`` and return the positive value ``query`` reports in ``field`` (a controller
        without the query, error code 1, is taken at its word)."""
        self.link.command(f"{command} {value:.9g}")

        def check(r: Reply) -> None:
            if not float(r.fields[field]) > 0:
                raise ValueError(f"bad {field} {r.fields[field]!r}")

        try:
            return float(self.link.fields(query, check=check)[field])
        except ControllerError as e:
            if e.code != 1:
                raise
            return value

    def set_gain(self, gain: float) -> float:
        """Switch the amplifier's gain (``GAIN n``) and return the one it reports (``GAIN?``; a controller without
        it is taken at its word)."""
        actual = self._set_and_read_back("GAIN", "GAIN?", "gain", gain)
        if abs(actual - gain) > 1e-6 * gain:
            raise DeviceError(f"{self.link.name}: gain {gain:g} requested, the amplifier reports {actual:g}")
        self.gain = actual
        return actual

    def set_integration_time(self, seconds: float) -> float:
        """Set the integration time per repeat (``INT``, s) and return the one the detector reports (``INT?``),
        which later readings are checked against. A detector that rounds the setting is believed; one without
        ``INT?`` is taken at its word."""
        before = self.integration_time_s
        actual = self._set_and_read_back("INT", "INT?", "t_int", seconds)
        if abs(actual - seconds) > _T_INT_RTOL * seconds:
            log.warning("%s: integration time %.6g s requested, the detector uses %.6g s", self.link.name, seconds,
                        actual)
        self.integration_time_s = actual
        if self.summing and actual != before:  # a summing ADC's saturation: read it for the time now set
            d = self.link.fields("DETECTOR?", check=_check_detector)
            self.saturation = min(self._config_saturation, float(d["saturation"]))
        return actual

    def _parse(self, f: dict[str, str], n: int) -> Reading:
        if int(f["n"]) != n:
            raise ValueError(f"n={f['n']} for {n} repeats")
        mean = _floats(f["mean"])
        std = _floats(f["std"])
        sat = int(f["sat"])
        if mean.size != self.n_channels or std.size != self.n_channels or not 0 <= sat <= n:
            raise ValueError("wrong number of channels or sat count")
        if np.any(std < 0):
            raise ValueError("negative std")
        if "gain" in f and self.gain is not None and abs(float(f["gain"]) - self.gain) > 1e-6 * self.gain:
            raise ValueError(f"gain={f['gain']}, but the gain is {self.gain:g}")
        if "t_int" in f:  # catches a corrupt digit, or a controller that lost its INT setting (power cycle)
            t_int = float(f["t_int"])
            if not abs(t_int - self.integration_time_s) <= _T_INT_RTOL * self.integration_time_s:
                raise ValueError(f"t_int={f['t_int']}, but the integration time is {self.integration_time_s:.6g} s")
        if "values" in f:  # photodiode: the raw repeats must agree with mean and std (catches corrupt digits)
            vals = _floats(f["values"])
            if vals.size != n:
                raise ValueError(f"{vals.size} values for n={n}")
            if abs(vals.mean() - mean[0]) > 0.0051:
                raise ValueError("values disagree with mean")
            if n > 1 and abs(vals.std(ddof=1) - std[0]) > 0.0051:
                raise ValueError("values disagree with std")
            sat = max(sat, int(np.sum(vals >= self.saturation)))
        mon = float(f["monitor"]) / self.integration_time_s if "monitor" in f else None  # a rate: counts/s
        return Reading(mean, std, n, sat, mon)

    def _read(self, word: str, n: int) -> Reading:
        """``word n`` (READ or DARK); if its reply keeps failing (the longer the reply, the likelier a corrupt
        byte), the ``n`` repeats are read in two halves, recursively, and pooled: one repeat per command at
        worst, so a noisy line slows a reading down instead of stopping the capture."""
        out: list[Reading] = []

        def check(reply: Reply) -> None:
            out.append(self._parse(reply.fields, n))

        try:
            self.link.command(f"{word} {n}", expect_s=n * self.integration_time_s, check=check)
        except CommError:
            if self.link.dead or n < 2:
                raise
            k = n // 2
            log.info("%s: %s %d kept failing; reading it as %d + %d repeats", self.link.name, word, n, k, n - k)
            return pool(self._read(word, k), self._read(word, n - k))
        return out[-1]

    def read(self, n: int) -> Reading:
        """``n`` repeats with the source on (raw counts per channel) at the present integration time."""
        return self._read("READ", n)

    def dark(self, n: int) -> Reading:
        """``n`` repeats with the source off / shutter closed."""
        return self._read("DARK", n)

    def describe(self) -> dict[str, Any]:
        """Type, channels, integration time (s) and saturation (counts) of the detector."""
        return {"type": self.type, "channels": len(self.channels), "integration_time_s": self.integration_time_s,
                "saturation": self.saturation}

    def set_sample(self, which: str) -> bool:
        """Sample changer: "REF" (white reference) or "TARGET". Without a changer, ask the operator (then True)."""
        if self.has_sample_changer:
            try:
                self.link.command(f"SAMPLE {which}")
                return False
            except ControllerError as e:
                if e.code not in (1, 10):
                    raise
                self.has_sample_changer = False
        if which == "TARGET" and self.manual_swap is None:
            return False  # nothing to ask: the sample is in place unless we asked for the reference
        if self.manual_swap is None:
            raise DeviceError(f"{self.link.name}: no sample changer (SAMPLE not supported) and no operator "
                              "prompt: mount the white reference by hand, or use absolute calibration")
        self.manual_swap(which)
        return True

    def time(self) -> float | None:
        """The controller's clock (s): simulated time on the simulator; None if not supported."""
        if not self.has_time:
            return None
        def check(r: Reply) -> None:
            if not float(r.fields["t"]) >= 0:
                raise ValueError(f"bad time {r.fields['t']!r}")

        return float(self.link.fields("TIME?", check=check)["t"])

    def dwell(self, seconds: float) -> None:
        """Wait ``seconds`` of bench time (DWELL on the controller: simulated time on the simulator)."""
        if seconds > 0 and self.has_dwell:
            self.link.command(f"DWELL {seconds:.6g}", expect_s=seconds)
        elif seconds > 0:
            time.sleep(seconds)


def _check_detector(reply: Reply) -> None:
    f = reply.fields  # every field used, parsed once here: a corrupt byte in any is a corrupt reply, read again
    if f["type"] not in ("photodiode", "spectrometer"):
        raise ValueError(f"unknown detector type {f['type']!r}")
    int(f["channels"])
    float(f["saturation"])
    float(f["t_int"])
    _ = [_floats(f[key]) for key in ("gains", "wavelengths") if key in f]


# --- stepper axes ----------------------------------------------------------------------------------------------


class SerialAxes:
    """Light and detector arms (and an optional stage) on the stepper controller; angles in degrees."""

    def __init__(self, link: SerialLink, axes: dict[str, Axis], tolerance_deg: float, timeout_s: float,
                 retries: int, poll_interval_s: float = 0.01) -> None:
        self.link = link
        self.axes = axes
        self.tolerance_deg = tolerance_deg
        self.timeout_s = timeout_s
        self.retries = retries
        self.poll_interval_s = poll_interval_s
        self.goal: dict[str, float] = {}
        self.cancel: Callable[[], None] = lambda: None

    def connect(self) -> None:
        """Check the controller drives our axes, clear a latched alarm, home if needed, move the stage to park."""
        info = self.link.fields("ID?")
        letters = set(info.get("axes", "-").split(","))
        if info.get("motion") != "serial":
            raise DeviceError(f"{self.link.name} on {self.link.port}: the controller drives no axes "
                              f"(ID? motion={info.get('motion')}); is this a Dynamixel bench?")
        for name, ax in self.axes.items():
            if ax.letter not in letters:
                raise DeviceError(f"{self.link.name}: axis {ax.letter} ({name} arm) is not on the controller "
                                  f"(axes={info.get('axes')})")
        st = self.status()
        if st["state"] == "Alarm" or int(st.get("alarm", "0")):
            log.warning("%s: alarm %s latched from before (%s); RESET", self.link.name, st.get("alarm"),
                        ALARM_TEXT.get(int(st.get("alarm", "0")), "alarm"))
            self.link.command("RESET")
            st = self.status()
        if st.get("homed") == "0":
            log.info("%s: homing all axes", self.link.name)
            self.link.command("HOME", busy_ok=True)
            self._wait(None, check_cancel=False)
        if "stage" in self.axes:
            self.move({"stage": self.axes["stage"].park_deg})

    def status(self) -> dict[str, str]:
        def check(r: Reply) -> None:
            f = r.fields
            if f["state"] not in ("Idle", "Moving", "Alarm"):
                raise ValueError(f"state {f['state']!r}")
            float(f["t"])
            for ax in self.axes.values():
                int(f[ax.letter])
            int(f.get("alarm", "0"))

        return self.link.fields("STATUS?", check=check)

    def positions(self) -> dict[str, float]:
        """Present axis angles (deg) from the step counters."""
        st = self.status()
        return {name: ax.units_to_deg(int(st[ax.letter])) for name, ax in self.axes.items()}

    def _send(self, goals: dict[str, float]) -> None:
        parts = " ".join(f"{self.axes[n].letter}{round(self.axes[n].deg_to_units(d))}" for n, d in goals.items())
        self.link.command(f"MOVE {parts}", busy_ok=True)

    def move(self, goals: dict[str, float], check_cancel: bool = True) -> None:
        """Move the named axes to ``goals`` (deg) at once and wait until idle and in position."""
        self.goal.update(goals)
        self._send(goals)
        self._wait(goals, check_cancel)

    def _wait(self, goals: dict[str, float] | None, check_cancel: bool = True) -> None:
        t_end = time.monotonic() + self.timeout_s
        resends = 0
        confirmed = False
        while True:
            if check_cancel:
                self.cancel()
            st = self.status()
            alarm = int(st.get("alarm", "0"))
            if st["state"] == "Alarm" or alarm:
                self._alarm_stop(alarm)
            if st["state"] == "Idle":
                off = {}
                for name, g in (goals or {}).items():
                    ax = self.axes[name]
                    deg = ax.units_to_deg(int(st[ax.letter]))
                    if abs(deg - g) > self.tolerance_deg:
                        off[name] = deg
                if not off:
                    if confirmed:  # two consistent replies in a row: not fooled by a corrupt digit
                        return
                    confirmed = True
                    continue
                confirmed = False
                if resends >= self.retries:
                    name, deg = next(iter(off.items()))
                    raise DeviceError(f"{self.link.name}: axis {self.axes[name].letter} ({name} arm) stopped at "
                                      f"{deg:.3f} deg, not at its goal {goals[name]:.3f} deg (tolerance "  # type: ignore[index]
                                      f"{self.tolerance_deg:g}) after {resends} re-sends")
                resends += 1
                log.warning("%s: idle but not in position (%s); re-sending the move", self.link.name, off)
                self._send(goals)  # type: ignore[arg-type]
                continue
            confirmed = False
            if time.monotonic() > t_end:
                self.stop()
                raise DeviceError(f"{self.link.name}: axes still moving after {self.timeout_s:g} s "
                                  f"(goals {goals}); stopped")
            if self.poll_interval_s:
                time.sleep(self.poll_interval_s)

    def _alarm_stop(self, alarm: int) -> None:
        try:
            self.link.command("STOP")
        except Exception:  # pragma: no cover - best effort
            pass
        raise HardwareError(f"{self.link.name} on {self.link.port}: alarm {alarm} "
                            f"({ALARM_TEXT.get(alarm, 'alarm')}); the axes were stopped. Check the arms for "
                            "obstructions; a resume sends RESET and re-homes if needed")

    def stop(self) -> None:
        """Stop all axes where they are (best effort)."""
        if self.link.dead:
            log.error("%s on %s is gone: cannot stop the axes; cut the motor power", self.link.name, self.link.port)
            return
        try:
            self.link.command("STOP")
        except Exception as e:  # pragma: no cover - best effort
            log.warning("%s: STOP failed: %s", self.link.name, e)

    def release(self) -> None:
        """Steppers have no torque-off command on this protocol: stop them."""
        self.stop()

    def healthy(self) -> bool:
        if self.link.dead:
            return False
        try:
            st = self.status()
        except Exception:
            return False
        return st["state"] != "Alarm" and not int(st.get("alarm", "0"))



def _open_axes(o: Opening) -> SerialAxes:
    """The stepper arms on the serial controller's link (which the bench opens and closes)."""
    assert o.link is not None
    m = o.cfg.motion
    return SerialAxes(o.link, o.cfg.axes, m.tolerance_deg, m.timeout_s, m.retries, m.poll_interval_s)


def _open_detector(o: Opening) -> SerialDetector:
    """The detector board's photodiode or spectrometer on its link (auto-ranging starts at the highest gain)."""
    assert o.link is not None
    d = o.cfg.detector
    det = SerialDetector(o.link, d.type, d.integration_time_s, d.saturation, d.gains,
                         start_gain=max(d.gains) if d.gains and d.auto_range else None)
    det.chop = d.chop
    return det


def _leave_to_the_link(device: Any) -> None:
    """A device on the shared link: the bench closes the link itself."""


_BOARD = "[bench].serial_port", "[bench].serial_baudrate"
#: The drivers of the serial text protocol (:mod:`acquisition.devices.registry`): ``[bench].motion = "serial"``
#: (stepper arms on the controller that also reads the detector), and the detector board's ``[detector].type``
#: ``"photodiode"`` and ``"spectrometer"``.
AXES_DRIVER = Driver("serial", "motion", MotionTable, (Port("serial", *_BOARD, "stepper controller"),), _open_axes,
                     _leave_to_the_link)
_DETECTOR_PORT = Port("serial", *_BOARD, "detector controller")
PHOTODIODE_DRIVER = Driver("photodiode", "detector", DetectorTable, (_DETECTOR_PORT,), _open_detector)
SPECTROMETER_DRIVER = Driver("spectrometer", "detector", DetectorTable, (_DETECTOR_PORT,), _open_detector)
