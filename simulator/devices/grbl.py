"""A virtual GRBL 1.1 controller: the subset of GRBL's serial interface that ``acquisition.devices.grbl`` uses,
spoken as GRBL documents it (gnea/grbl ``doc/markdown/interface.md``, ``commands.md``), written from that
documentation (none of GRBL's code).

* lines: G-code (``G0``/``G1`` with ``G90``/``G91``/``G53``, ``G4 P``, ``G21``, ``F``), ``$$``, ``$I``, ``$H``
  (homing onto switches at machine 0, pulled off by ``$27``), ``$HX``/``$HY``, ``$X``, ``$N=value``, answered
  ``ok``/``error:N``;
* the homing cycles of the firmware the bench was flashed with (``[simulator].grbl_build``): "gonio"
  (``firmware/grbl``: X and Y in one cycle; ``$HX``/``$HY``; 'H' in ``$I``'s options) or "stock" (GRBL 1.1h's
  release: Z first, then X and Y; the bench has no Z switch, so ``$H`` searches Z for 1.5 x ``$132`` and ends in
  ``ALARM:9``, reset, the arms unmoved);
* realtime bytes picked out of the stream: ``?`` (``<Idle|MPos:x,y,z|FS:f,0>``), ``!`` (feed hold:
  ``Hold:1`` while decelerating, ``Hold:0`` once stopped), ``~`` (resume), 0x18 (soft reset: welcome line; in
  motion ``ALARM:3`` and the position lost);
* pushes: ``ALARM:N``, ``[MSG:...]``, the welcome line ``Grbl 1.1h ['$' for help]``;
* soft limits (``$20``: a target outside ``[-$130, 0]`` -> ``ALARM:2``, reset to continue), the alarm lock (G-code
  refused with ``error:9``), and a power-up in alarm when homing is enabled (``$22``).

Axes X (light arm) and Y (detector arm) in GRBL's "mm", which are degrees on this bench: ``steps = MPos * $10x``
are the bench file's controller units (``steps = zero_offset + direction * units_per_deg * deg``). A straight
line moves both axes at once and both arrive together (GRBL's planner: the line's speed and acceleration are the
largest that keep every axis within its ``$11x``/``$12x``). The arms' physical position is the motor's plus a
hidden slip, which a reset in motion changes (lost steps) and homing clears.
"""

from __future__ import annotations

import logging
import math
import re

from simulator.config import BenchConfig
from simulator.world.clock import Paced, SimClock
from simulator.world.motion import AxisMotion

log = logging.getLogger("simulator.grbl")

__all__ = ["VirtualGrbl", "WELCOME", "default_settings"]

WELCOME = "Grbl 1.1h ['$' for help]"
VERSION = "[VER:1.1h.20190830:gonio-sim]"
#: ``$I``'s build options and homing cycles (axis indices, one tuple per cycle) of each firmware build
OPTIONS = {"gonio": "[OPT:VH,15,128]", "stock": "[OPT:V,15,128]"}
HOMING_CYCLES = {"gonio": ((0, 1),), "stock": ((2,), (0, 1))}
#: GRBL's homing search: 1.5 x the largest travel ($13x) of the cycle's axes
SEARCH_SCALAR = 1.5
LETTERS = ("X", "Y", "Z")
_WORD = re.compile(r"([A-Z])([-+]?(?:\d+\.?\d*|\.\d+))")
_SET = re.compile(r"^\$(\d{1,3})=([-+]?(?:\d+\.?\d*|\.\d+))$")
MAX_LINE = 80  # GRBL's LINE_BUFFER_SIZE
#: the lost steps of a reset in motion, as a fraction of the distance still to go (the arms coast on)
COAST_FRACTION = 0.1


def default_settings(cfg: BenchConfig) -> dict[int, float]:
    """GRBL 1.1h's defaults with the bench file's axes: ``$100/$101`` from ``[axes.*].units_per_deg``,
    ``$110/$111`` and ``$120/$121`` from ``[simulator].stepper_velocity_deg_s`` / ``_acceleration_deg_s2``, and
    ``[motion.grbl].homing`` (default ``[simulator].homing_required``) as ``$22`` (the arms have switches) and its
    ``soft_limits`` as ``$20``."""
    s = cfg.sim
    homing = cfg.grbl.homing
    soft = cfg.grbl.soft_limits and homing
    out = {0: 10, 1: 25, 2: 0, 3: 0, 4: 0, 5: 0, 6: 0, 10: 1, 11: 0.010, 12: 0.002, 13: 0, 20: float(soft), 21: 0,
           22: float(homing), 23: 0, 24: 25.0, 25: 500.0, 26: 250, 27: 1.0, 30: 1000, 31: 0, 32: 0,
           102: 250.0, 112: 500.0, 122: 10.0, 132: 200.0}
    for i, name in enumerate(("light", "detector")):
        ax = cfg.axes[name]
        out[100 + i] = abs(ax.units_per_deg)
        out[110 + i] = s.stepper_velocity_deg_s * 60.0
        out[120 + i] = s.stepper_acceleration_deg_s2
        # the travel from the switch (machine 0) to the far end of the arm's range
        ends = [ax.deg_to_units(d) / ax.units_per_deg for d in (ax.min_deg, ax.max_deg)]
        out[130 + i] = round(max(1.0, -min(ends)), 3)
    return out


class VirtualGrbl(Paced):
    """GRBL behind one serial port: feed bytes to :meth:`process`, send back what it returns."""

    def __init__(self, cfg: BenchConfig, clock: SimClock, settings: dict[int, float] | None = None) -> None:
        self.cfg = cfg
        self.clock = clock
        self.settings = dict(settings if settings is not None else default_settings(cfg))
        self.names = ("light", "detector")
        self.build = getattr(cfg.sim, "grbl_build", "gonio")
        self.motors = [AxisMotion(0.0) for _ in self.names]
        homing = bool(self.settings[22])
        # with switches the arms start where they were parked; without, at machine 0 (where GRBL's count starts)
        self.slip = [cfg.axes[n].deg_to_units(cfg.axes[n].park_deg) if homing else 0.0 for n in self.names]
        self.state = "Alarm" if homing else "Idle"
        self.alarm = 0
        self.hold_end: float | None = None  # feed hold: the time the deceleration ends
        self.queue: list[list[float]] = []  # planned blocks (targets in mm) not started yet
        self.goal_mm = [0.0, 0.0]
        self.absolute = True
        self.feed = 0.0
        self._buf = bytearray()
        self._wait = 0.0
        self._reset_to_continue = False
        self.out = [WELCOME] + (["[MSG:'$H'|'$X' to unlock]"] if homing else [])  # power-up lines, once read

    # -- time ----------------------------------------------------------------------------------------------------
    def _moving(self, t: float) -> bool:
        return any(m.profiling(t) for m in self.motors)

    def _update(self, t: float) -> None:
        """Start queued blocks whose predecessor ended; the cycle ends when nothing is left."""
        while self.queue and not self._moving(t) and self.state == "Run":
            t0 = max(m.profile.t_end for m in self.motors)
            self._start(self.queue.pop(0), min(t, max(t0, 0.0)))
        if self.state == "Run" and not self._moving(t) and not self.queue:
            self.state = "Idle"
        if self.state == "Hold" and self.hold_end is not None and t >= self.hold_end:
            self.hold_end = None

    def _complete(self) -> None:
        """Fast time: let the motion run to its end before a status report (as the serial controller does)."""
        if self.clock.fast and self.state == "Run":
            while True:
                self.clock.jump_to(max(m.profile.t_end for m in self.motors))
                self._update(self.clock.now())
                if not self.queue or self.state != "Run":
                    break

    def mpos(self, t: float) -> list[float]:
        return [m.motor_position(t) / self.settings[100 + i] for i, m in enumerate(self.motors)]

    def arm_angles(self, t: float) -> tuple[float, float]:
        """Physical (theta_i, theta_o) in degrees at simulated time ``t``: motor steps plus slip."""
        ang = [self.cfg.axes[n].units_to_deg(self.motors[i].motor_position(t) + self.slip[i])
               for i, n in enumerate(self.names)]
        return ang[0], ang[1]

    # -- motion ----------------------------------------------------------------------------------------------------
    def _start(self, target_mm: list[float], t: float) -> None:
        """One straight line to ``target_mm`` from the present position: both axes arrive together."""
        steps = [round(target_mm[i] * self.settings[100 + i]) for i in range(2)]
        d = [abs(steps[i] - self.motors[i].motor_position(t)) for i in range(2)]
        moving = [i for i in range(2) if d[i] > 0]
        if not moving:
            return
        # per unit of the line's parameter s in [0, 1]: the largest speed/acceleration no axis exceeds
        vs = min(self.settings[110 + i] / 60.0 * self.settings[100 + i] / d[i] for i in moving)
        acc = min(self.settings[120 + i] * self.settings[100 + i] / d[i] for i in moving)
        if self.feed > 0 and self._g1:
            vs = min(vs, min(self.feed / 60.0 * self.settings[100 + i] / d[i] for i in moving))
        for i in range(2):
            self.motors[i].start(float(steps[i]), t, vs * d[i] if d[i] else math.inf, acc * d[i] if d[i] else math.inf)

    def _stop_now(self, t: float) -> None:
        for m in self.motors:
            m.stop(t)
        self.queue.clear()

    # -- bytes ---------------------------------------------------------------------------------------------------
    def process(self, data: bytes) -> bytes:
        """Received bytes -> reply bytes (realtime bytes at once, then one reply per complete line)."""
        lines: list[str] = self.out
        self.out = []
        t = self.clock.now()
        self._update(t)
        for b in data:
            ch = bytes([b])
            if ch == b"?":
                self._complete()
                self._update(self.clock.now())
                lines.append(self.status(self.clock.now()))
            elif ch == b"!":
                self._feed_hold(self.clock.now())
            elif ch == b"~":
                self._resume(self.clock.now())
            elif ch == b"\x18":
                lines += self._soft_reset(self.clock.now())
                self._buf.clear()
            elif ch in (b"\n", b"\r"):
                text = self._buf.decode("ascii", errors="replace").strip()
                self._buf.clear()
                if text or ch == b"\n":
                    lines += self.line(text)
            elif b >= 0x80:
                continue  # overrides: not simulated
            else:
                self._buf += ch
        return "".join(ln + "\r\n" for ln in lines).encode("ascii")

    def status(self, t: float) -> str:
        state = self.state
        if state == "Hold":
            state = "Hold:1" if self.hold_end is not None and t < self.hold_end else "Hold:0"
        pos = ",".join(f"{v:.3f}" for v in self.mpos(t)) + ",0.000"
        speed = 0.0
        if self._moving(t):
            speed = math.hypot(*(m.motor_velocity(t) / self.settings[100 + i] for i, m in enumerate(self.motors)))
        return f"<{state}|MPos:{pos}|FS:{speed * 60:.0f},0>"

    def _feed_hold(self, t: float) -> None:
        if self.state != "Run":
            return
        # decelerate at the slowest axis' acceleration, then hold: the remaining blocks wait for '~'
        v = [abs(m.motor_velocity(t)) for m in self.motors]
        dec = [v[i] / (self.settings[120 + i] * self.settings[100 + i]) for i in range(2)]
        t_stop = max(dec)
        for i, m in enumerate(self.motors):
            if v[i] > 0:
                sign = 1.0 if m.goal >= m.motor_position(t) else -1.0
                stop_at = m.motor_position(t) + sign * 0.5 * v[i] * t_stop
                m.start(stop_at, t, v[i], v[i] / t_stop if t_stop > 0 else math.inf)
        self._held_goal = list(self.goal_mm)
        self.state = "Hold"
        self.hold_end = t + t_stop

    def _resume(self, t: float) -> None:
        if self.state == "Hold" and (self.hold_end is None or t >= self.hold_end):
            self.hold_end = None
            self.state = "Run"
            self._start(self._held_goal, t)

    def _soft_reset(self, t: float) -> list[str]:
        out = []
        if self.state in ("Run", "Home") or (self.state == "Hold" and self.hold_end is not None and t < self.hold_end):
            # killed in motion: the arms coast on past the counted steps (the count stops, the arms do not)
            for i, m in enumerate(self.motors):
                self.slip[i] += COAST_FRACTION * (m.goal - m.motor_position(t))
            self.alarm = 3
            out.append("ALARM:3")
        self._stop_now(t)
        self.hold_end = None
        self._reset_to_continue = False
        if self.alarm or self.state == "Alarm":
            self.state = "Alarm"
            out += [WELCOME, "[MSG:'$H'|'$X' to unlock]"]
        else:
            self.state = "Idle"
            out.append(WELCOME)
        self.absolute, self.feed = True, 0.0
        self.goal_mm = self.mpos(t)[:2]
        return out

    # -- lines ---------------------------------------------------------------------------------------------------
    def line(self, text: str) -> list[str]:
        """One command line -> its reply lines (the last is ``ok`` or ``error:N``)."""
        text = text.replace(" ", "").upper()
        if len(text) > MAX_LINE:
            return ["error:11"]
        if self._reset_to_continue:
            return ["error:9"]
        if not text:
            return ["ok"]
        if text.startswith("$"):
            return self._dollar(text)
        if self.state == "Alarm":
            return ["error:9"]
        return self._gcode(text)

    def _dollar(self, text: str) -> list[str]:
        idle = self.state in ("Idle", "Alarm")
        if text == "$$":
            return [f"${k}={v:.3f}" if k in (11, 12, 24, 25, 27) or k >= 100 else f"${k}={v:.0f}"
                    for k, v in sorted(self.settings.items())] + ["ok"]
        if text == "$I":
            return [VERSION, OPTIONS[self.build], "ok"]
        if text == "$X":
            if self.state == "Alarm":
                self.state, self.alarm = "Idle", 0
                return ["[MSG:Caution: Unlocked]", "ok"]
            return ["ok"]
        if text.startswith("$H"):
            axis = {"$H": None, "$HX": 0, "$HY": 1}.get(text, -1)
            if axis == -1 or (axis is not None and self.build == "stock"):  # single-axis homing: our build only
                return ["error:3"]
            if not self.settings[22]:
                return ["error:5"]
            if not idle:
                return ["error:8"]
            cycles = HOMING_CYCLES[self.build] if axis is None else ((axis,),)
            return self._home(cycles)
        m = _SET.match(text)
        if m:
            if not idle:
                return ["error:8"]
            n, v = int(m.group(1)), float(m.group(2))
            if n not in self.settings:
                return ["error:3"]
            if v < 0:
                return ["error:4"]
            if n == 20 and v and not self.settings[22]:
                return ["error:10"]
            self.settings[n] = v
            return ["ok"]
        return ["error:3"]

    def _home(self, cycles: tuple[tuple[int, ...], ...]) -> list[str]:
        """GRBL's homing cycles in order: each seeks its axes' switches (machine 0) at ``$25`` together, then
        pulls off by ``$27`` (MPos = -$27 afterwards). An axis without a switch (Z on this bench) is searched
        for 1.5 x its ``$13x`` and the cycle ends in ``ALARM:9`` with a reset (GRBL's behaviour)."""
        seek, locate, pull = self.settings[25] / 60.0, self.settings[24] / 60.0, self.settings[27]
        for cycle in cycles:
            t = self.clock.now()
            if any(i >= 2 for i in cycle):  # no switch: the whole search distance, then the alarm
                self._advance(SEARCH_SCALAR * max(self.settings[130 + i] for i in cycle) / seek)
                self.alarm, self.state = 9, "Alarm"
                return ["ALARM:9", "ok"] + self._soft_reset(self.clock.now())
            dist = max(abs(self.motors[i].motor_position(t) + self.slip[i]) / self.settings[100 + i] for i in cycle)
            self._advance(dist / seek + 2 * pull / locate)
            t = self.clock.now() if self.clock.fast else t
            for i in cycle:
                m = self.motors[i]
                m.profile = type(m.profile)(-pull * self.settings[100 + i], -pull * self.settings[100 + i], t)
                m.stall_time = m.frozen_at = None
                self.slip[i] = 0.0
                self.goal_mm[i] = -pull
        self.state, self.alarm = "Idle", 0
        return ["ok"]

    def _gcode(self, text: str) -> list[str]:
        words = _WORD.findall(text)
        if "".join(a + b for a, b in words) != text:
            return ["error:1"]
        axes: dict[str, float] = {}
        machine = False
        motion = None
        dwell = None
        for letter, num in words:
            v = float(num)
            if letter == "G":
                if v in (0, 1):
                    motion = int(v)
                elif v == 4:
                    motion = 4
                elif v == 53:
                    machine = True
                elif v == 90:
                    self.absolute = True
                elif v == 91:
                    self.absolute = False
                elif v not in (17, 21, 54, 94):
                    return ["error:20"]
            elif letter in LETTERS:
                axes[letter] = v
            elif letter == "F":
                self.feed = v
            elif letter == "P":
                dwell = v
            elif letter in ("N", "M"):
                continue
            else:
                return ["error:20"]
        if motion == 4:
            if dwell is None:
                return ["error:28"]
            self._complete()
            self._advance(dwell)
            return ["ok"]
        if not axes:
            return ["ok"] if motion is None else ["error:26"]
        if motion == 1 and self.feed <= 0:
            return ["error:22"]
        self._g1 = motion == 1
        base = self.goal_mm
        target = [axes.get(LETTERS[i], base[i] if (self.absolute or machine) else 0.0) for i in range(2)]
        if not self.absolute and not machine:
            target = [base[i] + target[i] for i in range(2)]
        if self.settings[20] and any(not -self.settings[130 + i] - 1e-9 <= target[i] <= 1e-9 for i in range(2)):
            t = self.clock.now()
            self._stop_now(t)
            self.state, self.alarm = "Alarm", 2
            self._reset_to_continue = True
            return ["ALARM:2", "[MSG:Reset to continue]", "ok"]
        self.goal_mm = target
        t = self.clock.now()
        if self.state == "Run" or self.state == "Hold":
            self.queue.append(target)
        else:
            self.state = "Run"
            self._start(target, t)
            self._update(t)
        return ["ok"]

    _g1 = False
    _held_goal: list[float] = [0.0, 0.0]
