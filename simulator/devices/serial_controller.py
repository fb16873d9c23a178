"""Text-protocol controller (stepper axes and detector ADC); the protocol is specified in docs/serial-protocol.md.

One command a line (``\\n``, ``\\r\\n`` or ``\\r``); every command gets zero or more data lines and then exactly one
final line, ``ok`` or ``error:N``. A command that raises an alarm sends ``ALARM:N`` just before its ``error:N``.
Nothing is ever sent unsolicited. Axis positions are integer controller steps:
``steps = zero_offset + direction * units_per_deg * deg`` with the values of the config's ``[axes.*]``.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np

from reconstruction.schema.bench import Axis
from simulator.config import BenchConfig
from simulator.world.clock import Paced, SimClock
from simulator.world.faults import FaultInjector
from simulator.world.frontend import ADC_LSB_V, SAMPLE_PERIOD_S
from simulator.world.motion import AxisMotion
from simulator.world.physics import BenchPhysics

log = logging.getLogger("simulator.serial")

VERSION = "0.1.0"
MAX_LINE = 256
MAX_REPEATS = 1000

E_UNKNOWN = 1
E_ARGUMENT = 2
E_SOFT_LIMIT = 3
E_LINE_TOO_LONG = 4
E_NOT_HOMED = 8
E_ALARM_LOCK = 9
E_NOT_AVAILABLE = 10
E_BUSY = 11
E_COLLISION = 20
E_STALL = 21


def _one_float(args: list[str], lo: float, hi: float) -> float | None:
    """The single numeric argument of a command if it lies in [lo, hi], else None (the caller answers error:2)."""
    if len(args) != 1:
        return None
    try:
        v = float(args[0])
    except ValueError:
        return None
    return v if lo <= v <= hi else None

ERROR_TEXT = {
    E_UNKNOWN: "unknown command",
    E_ARGUMENT: "bad or missing argument",
    E_SOFT_LIMIT: "target outside the axis soft limits",
    E_LINE_TOO_LONG: "line too long",
    E_NOT_HOMED: "not homed: send HOME",
    E_ALARM_LOCK: "alarm active: send RESET",
    E_NOT_AVAILABLE: "not available on this bench",
    E_BUSY: "axes are moving",
    E_COLLISION: "collision: arms closer than the minimum separation",
    E_STALL: "axis stalled",
}


class StepperAxis:
    """One open-loop stepper axis with stall detection; positions in steps."""

    def __init__(self, cfg: Axis, sim_cfg, clock: SimClock) -> None:
        self.cfg = cfg
        self.clock = clock
        upd = abs(cfg.units_per_deg)
        self.v_max = sim_cfg.stepper_velocity_deg_s * upd
        self.a_max = sim_cfg.stepper_acceleration_deg_s2 * upd
        self.motion = AxisMotion(
            cfg.deg_to_units(cfg.park_deg),
            backlash=sim_cfg.backlash_deg * upd,
            ringing=sim_cfg.settle_ringing_deg * upd,
            settle_time=sim_cfg.settle_time_s,
        )

    @property
    def letter(self) -> str:
        return self.cfg.letter

    def steps(self, t: float) -> int:
        return int(round(self.motion.motor_position(t)))

    def stalled(self, t: float) -> bool:
        return self.motion.stall_time is not None and t >= self.motion.stall_time

    def arm_deg(self, t: float) -> float:
        return self.cfg.units_to_deg(self.motion.arm_position(t))

    def goal_deg(self) -> float:
        return self.cfg.units_to_deg(self.motion.goal)

    def event_time(self) -> float:
        """When this axis' motion is over (or its stall is detected)."""
        if self.motion.stall_time is not None:
            return self.motion.stall_time
        return self.motion.settled_time()


class SerialController(Paced):
    """Interpreter of the text protocol. Feed bytes with :meth:`process`; it returns the reply bytes.

    ``axes``: stepper axes served by this controller (empty on a Dynamixel bench, where it only serves the
    detector). ``arm_angles(t)`` gives the physical (theta_i, theta_o) in degrees at simulated time ``t`` and
    ``settle_axes()`` completes pending motion of axes it does not own (used in fast time before a reading).
    """

    def __init__(self, cfg: BenchConfig, clock: SimClock, physics: BenchPhysics, comm_faults: FaultInjector,
                 motion_faults: FaultInjector, axes: list[StepperAxis],
                 arm_angles: Callable[[float], tuple[float, float]] | None = None,
                 collision: Callable[[dict[str, float]], bool] | None = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.physics = physics
        self.comm_faults = comm_faults
        self.motion_faults = motion_faults
        self.axes = {a.letter: a for a in axes}
        self._arm_angles = arm_angles
        self._collision = collision
        self.alarm = 0
        self.chop = False  # CHOP ON: readings are the source's on-time minus as long off (the detector board's)
        self.homed = not cfg.sim.homing_required or not axes
        self._buf = bytearray()
        self._discarding = False
        self._wait = 0.0
        self.internal_errors = 0

    # -- byte interface ----------------------------------------------------------------------------------------
    def process(self, data: bytes) -> bytes:
        """Feed received bytes; return the reply bytes for every complete line. Never raises."""
        out = bytearray()
        self._buf += data
        while not self._wait:  # after a command that takes scaled time, the caller waits, then calls again
            idx = -1
            for sep in (b"\n", b"\r"):
                j = self._buf.find(sep)
                if j >= 0 and (idx < 0 or j < idx):
                    idx = j
            if idx < 0:
                if len(self._buf) > MAX_LINE:
                    self._buf.clear()
                    self._discarding = True
                break
            raw = bytes(self._buf[:idx])
            del self._buf[: idx + 1]
            if self._discarding:
                self._discarding = False
                lines = [f"error:{E_LINE_TOO_LONG}"]
            else:
                try:
                    text = raw.decode("ascii", errors="replace").strip()
                except Exception:  # pragma: no cover
                    text = ""
                if not text:
                    continue
                if len(text) > MAX_LINE:
                    lines = [f"error:{E_LINE_TOO_LONG}"]
                else:
                    try:
                        lines = self.handle_line(text)
                    except Exception:
                        log.exception("controller failure on %r", text)
                        self.internal_errors += 1
                        lines = [f"error:{E_UNKNOWN}"]
            reply = ("\n".join(lines) + "\n").encode("ascii")
            if self.comm_faults.drop_reply():
                log.info("fault: dropped reply to %r", raw)
                continue
            out += self.comm_faults.corrupt(reply)
        return bytes(out)

    # -- helpers -----------------------------------------------------------------------------------------------
    def arm_angles(self, t: float) -> tuple[float, float]:
        if self.axes:
            light = next((a for a in self.axes.values() if a.cfg.name == "light"), None)
            det = next((a for a in self.axes.values() if a.cfg.name == "detector"), None)
            return (light.arm_deg(t) if light else 0.0, det.arm_deg(t) if det else 0.0)
        if self._arm_angles is None:
            return (0.0, 0.0)
        return self._arm_angles(t)

    def _update_alarms(self, t: float) -> None:
        for a in self.axes.values():
            if a.stalled(t) and self.alarm == 0:
                self.alarm = E_STALL
                a.motion.stop(a.motion.stall_time)
                log.warning("axis %s: stalled (alarm 21)", a.letter)

    def _complete_motion(self) -> None:
        """Fast time: let pending motion finish (or its stall be detected) before a status/reading."""
        if not self.clock.fast:
            return
        ts = [a.event_time() for a in self.axes.values()]
        ts = [t for t in ts if math.isfinite(t)]
        if ts:
            self.clock.jump_to(max(ts))

    def _moving(self, t: float) -> bool:
        return any(a.motion.moving(t) for a in self.axes.values())

    @staticmethod
    def _err(n: int) -> list[str]:
        return [f"error:{n}"]

    # -- dispatch ----------------------------------------------------------------------------------------------
    def handle_line(self, line: str) -> list[str]:
        """Execute one command line; return reply lines (the last is ``ok`` or ``error:N``)."""
        parts = line.split()
        cmd = parts[0].upper()
        args = parts[1:]
        if cmd == "?":
            cmd = "STATUS?"
        fn = self._COMMANDS.get(cmd)
        if fn is None:
            return self._err(E_UNKNOWN)
        t = self.clock.now()
        self._update_alarms(t)
        return fn(self, args)

    def _cmd_help(self, args: list[str]) -> list[str]:
        return ["HELP " + " ".join(sorted(self._COMMANDS)), "ok"]

    def _cmd_id(self, args: list[str]) -> list[str]:
        motion = "serial" if self.axes else "none"
        axes = ",".join(self.axes) or "-"
        return [f"ID name=gonio-sim version={VERSION} motion={motion} axes={axes} "
                f"detector={self.physics.detector.type}", "ok"]

    def _cmd_status(self, args: list[str]) -> list[str]:
        self._complete_motion()
        t = self.clock.now()
        self._update_alarms(t)
        if self.alarm:
            state = "Alarm"
        elif self._moving(t):
            state = "Moving"
        else:
            state = "Idle"
        fields = [f"state={state}", f"t={t:.6f}"]
        fields += [f"{k}={a.steps(t)}" for k, a in self.axes.items()]
        fields += [f"homed={int(self.homed)}", f"sample={self.physics.sample}", f"alarm={self.alarm}"]
        return ["STATUS " + " ".join(fields), "ok"]

    def _cmd_time(self, args: list[str]) -> list[str]:
        return [f"TIME t={self.clock.now():.6f}", "ok"]

    def _cmd_dwell(self, args: list[str]) -> list[str]:
        dt = _one_float(args, 0.0, 3600.0)
        if dt is None:
            return self._err(E_ARGUMENT)
        self._advance(dt)
        return ["ok"]

    def _parse_targets(self, args: list[str]) -> dict[str, int] | int:
        targets: dict[str, int] = {}
        for a in args:
            a = a.upper().replace("=", "")
            if len(a) < 2:
                return E_ARGUMENT
            letter, num = a[0], a[1:]
            if letter not in self.axes:
                return E_NOT_AVAILABLE
            try:
                targets[letter] = int(num)
            except ValueError:
                return E_ARGUMENT
        return targets

    def _start_moves(self, targets: dict[str, float], homing: bool = False) -> list[str]:
        t = self.clock.now()
        if self.alarm:
            return self._err(E_ALARM_LOCK)
        if self._moving(t):
            return self._err(E_BUSY)
        for k, steps in targets.items():
            ax = self.axes[k]
            deg = ax.cfg.units_to_deg(steps)
            lo, hi = ax.cfg.min_deg, ax.cfg.max_deg
            if not (lo - 1e-9 <= deg <= hi + 1e-9):
                return self._err(E_SOFT_LIMIT)
        goals = {a.cfg.name: (a.cfg.units_to_deg(targets[k]) if k in targets else a.goal_deg())
                 for k, a in self.axes.items()}
        if self._collision is not None and self._collision(goals):
            self.alarm = E_COLLISION
            log.warning("move refused: arms would collide (goals %s)", goals)
            return [f"ALARM:{E_COLLISION}", f"error:{E_COLLISION}"]
        for k, steps in targets.items():
            ax = self.axes[k]
            stall = self.motion_faults.stall_fraction()
            ax.motion.start(float(steps), t, ax.v_max, ax.a_max, stall_fraction=stall)
            if stall is not None:
                log.warning("axis %s: fault: stall scheduled at t=%.3f s", k, ax.motion.stall_time)
        if homing:
            self.homed = True
        return ["ok"]

    def _cmd_move(self, args: list[str]) -> list[str]:
        if not self.axes:
            return self._err(E_NOT_AVAILABLE)
        if not args:
            return self._err(E_ARGUMENT)
        targets = self._parse_targets(args)
        if isinstance(targets, int):
            return self._err(targets)
        if not self.homed:
            return self._err(E_ALARM_LOCK if self.alarm else E_NOT_HOMED)
        return self._start_moves(targets)

    def _cmd_home(self, args: list[str]) -> list[str]:
        if not self.axes:
            return self._err(E_NOT_AVAILABLE)
        letters = [a.upper() for a in args] or list(self.axes)
        if any(k not in self.axes for k in letters):
            return self._err(E_NOT_AVAILABLE)
        targets = {k: round(self.axes[k].cfg.deg_to_units(self.axes[k].cfg.park_deg)) for k in letters}
        return self._start_moves(targets, homing=True)

    def _cmd_stop(self, args: list[str]) -> list[str]:
        t = self.clock.now()
        for a in self.axes.values():
            a.motion.stop(t)
        return ["ok"]

    def _cmd_reset(self, args: list[str]) -> list[str]:
        t = self.clock.now()
        if self.alarm:
            log.info("alarm %d cleared", self.alarm)
        for a in self.axes.values():
            if a.motion.stall_time is not None:
                a.motion.stop(min(t, a.motion.stall_time))
        self.alarm = 0
        return ["ok"]

    def _read_common(self, args: list[str], source_on: bool) -> list[str]:
        if len(args) > 1:
            return self._err(E_ARGUMENT)
        try:
            n = int(args[0]) if args else int(self.cfg.detector.repeats)
        except ValueError:
            return self._err(E_ARGUMENT)
        if not 1 <= n <= MAX_REPEATS:
            return self._err(E_ARGUMENT)
        det = self.physics.detector
        t_int = det.integration_time_s
        t0 = self.clock.now()
        times = t0 + (np.arange(n) + 0.5) * t_int
        angles = np.array([self.arm_angles(float(tk)) for tk in times])
        codes, sat = self.physics.read(angles[:, 0], angles[:, 1], source_on=source_on and self.physics.source_on,
                                       t_s=times)
        if self.chop:  # as long with the source off, subtracted: room light and offsets cancel
            off, sat_off = self.physics.read(angles[:, 0], angles[:, 1], source_on=False, t_s=times)
            codes, sat = codes - off, sat | sat_off
            self._advance(n * t_int)
        self._advance(n * t_int)
        tag = "READ" if source_on else "DARK"
        mean = codes.mean(axis=0)
        std = codes.std(axis=0, ddof=1) if n > 1 else np.zeros_like(mean)
        fields = [f"n={n}", f"sat={int(sat.sum())}", f"t_int={t_int:g}"]
        if self.physics.gains:
            fields.append(f"gain={det.gain:g}")
        if det.n_channels == 1:
            fields += [f"mean={mean[0]:.3f}", f"std={std[0]:.3f}",
                       "values=" + ",".join(str(int(v)) for v in codes[:, 0])]
        else:
            fields += ["mean=" + ",".join(f"{v:.2f}" for v in mean), "std=" + ",".join(f"{v:.2f}" for v in std)]
        if self.cfg.detector.monitor:  # as the board built with MONITOR=1: its monitor photodiode after the repeats
            fields.append(f"monitor={self._monitor_sum(source_on and self.physics.source_on, t_int)}")
        return [tag + " " + " ".join(fields), "ok"]

    def _monitor_sum(self, source_on: bool, t_int: float) -> int:
        """The monitor photodiode's ``monitor=`` field, as firmware/detector sends it: its amplifier's output
        (``[simulator].monitor_mv`` at the source's nominal power, times the source's drift now; 0 with the source
        off) in the ATmega's ADC codes, summed over one repeat's conversions (every 125 us), which take that time."""
        volts = (1e-3 * self.physics.cfg.sim.monitor_mv * float(self.physics.source_scale(self.clock.now()))
                 if source_on else 0.0)
        conversions = max(1, round(t_int / SAMPLE_PERIOD_S))
        self._advance(t_int)
        return int(round(min(volts / ADC_LSB_V, round(5.0 / ADC_LSB_V)) * conversions))

    def _cmd_read(self, args: list[str]) -> list[str]:
        return self._read_common(args, True)

    def _cmd_dark(self, args: list[str]) -> list[str]:
        return self._read_common(args, False)

    def _cmd_detector(self, args: list[str]) -> list[str]:
        det = self.physics.detector
        fields = [f"type={det.type}", f"channels={det.n_channels}", f"bits={det.adc_bits}",
                  f"gain={det.gain:g}", f"saturation={det.max_code:g}", f"t_int={det.integration_time_s:g}"]
        if self.physics.gains:
            fields.append("gains=" + ",".join(f"{g:g}" for g in self.physics.gains))
        if det.wavelengths_nm is not None:
            fields.append("wavelengths=" + ",".join(f"{w:g}" for w in det.wavelengths_nm))
        return ["DETECTOR " + " ".join(fields), "ok"]

    def _cmd_int(self, args: list[str]) -> list[str]:
        v = _one_float(args, 1e-5, 10.0)
        if v is None:
            return self._err(E_ARGUMENT)
        self.physics.detector.integration_time_s = v
        return ["ok"]

    def _cmd_int_q(self, args: list[str]) -> list[str]:
        return [f"INT t_int={self.physics.detector.integration_time_s:g}", "ok"]

    def _cmd_gain(self, args: list[str]) -> list[str]:
        gains = self.physics.gains
        v = _one_float(args, 0.001, 1e7) if gains else _one_float(args, 0.01, 1000.0)
        if v is None:
            return self._err(E_ARGUMENT)
        if gains:  # the amplifier's switchable gains only
            match = [g for g in gains if abs(g - v) <= 1e-6 * g]
            if not match:
                return self._err(E_ARGUMENT)
            v = match[0]
        self.physics.detector.gain = v
        return ["ok"]

    def _cmd_gain_q(self, args: list[str]) -> list[str]:
        return [f"GAIN gain={self.physics.detector.gain:g}", "ok"]

    def _cmd_sample(self, args: list[str]) -> list[str]:
        if len(args) != 1 or args[0].upper() not in ("REF", "TARGET"):
            return self._err(E_ARGUMENT)
        self.physics.sample = args[0].upper()
        log.info("sample changer: %s", self.physics.sample)
        return ["ok"]

    def _cmd_sample_q(self, args: list[str]) -> list[str]:
        return [f"SAMPLE sample={self.physics.sample}", "ok"]

    def _cmd_source(self, args: list[str]) -> list[str]:
        """``SOURCE ON|OFF``: the source's pin (the darks of a detector that is not the board's)."""
        if len(args) != 1 or args[0].upper() not in ("ON", "OFF"):
            return self._err(E_ARGUMENT)
        on = args[0].upper() == "ON"
        if on != self.physics.source_on:
            self.physics.source_switches += 1
        self.physics.source_on = on
        log.info("source: %s", args[0].upper())
        return ["ok"]

    def _cmd_chop(self, args: list[str]) -> list[str]:
        """``CHOP ON|OFF``: chopped readings, as the detector board makes them (docs/serial-protocol.md): here one
        half is the integration time with the source on, the other as long with it off."""
        if len(args) != 1 or args[0].upper() not in ("ON", "OFF"):
            return self._err(E_ARGUMENT)
        self.chop = args[0].upper() == "ON"
        return ["ok"]

    def _cmd_chop_q(self, args: list[str]) -> list[str]:
        return [f"CHOP chop={'ON' if self.chop else 'OFF'} half={self.physics.detector.integration_time_s:g}", "ok"]

    def _cmd_source_q(self, args: list[str]) -> list[str]:
        return [f"SOURCE source={'ON' if self.physics.source_on else 'OFF'}", "ok"]

    _COMMANDS = {
        "HELP": _cmd_help,
        "CHOP": _cmd_chop,
        "CHOP?": _cmd_chop_q,
        "ID?": _cmd_id,
        "STATUS?": _cmd_status,
        "TIME?": _cmd_time,
        "DWELL": _cmd_dwell,
        "MOVE": _cmd_move,
        "HOME": _cmd_home,
        "STOP": _cmd_stop,
        "RESET": _cmd_reset,
        "READ": _cmd_read,
        "DARK": _cmd_dark,
        "DETECTOR?": _cmd_detector,
        "INT": _cmd_int,
        "INT?": _cmd_int_q,
        "GAIN": _cmd_gain,
        "GAIN?": _cmd_gain_q,
        "SAMPLE": _cmd_sample,
        "SAMPLE?": _cmd_sample_q,
        "SOURCE": _cmd_source,
        "SOURCE?": _cmd_source_q,
    }
