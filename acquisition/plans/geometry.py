"""What an in-plane bench can reach and how fast: :class:`Geometry` (soft limits, the collision zone, the blind
spot, trapezoidal move times of both arms at once), why a point cannot be measured (:class:`Reason`,
:class:`Why`) and the identity of a point (:func:`point_key`). Angles in degrees, times in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from enum import Enum
from functools import cached_property
from typing import Any

import numpy as np

from acquisition.config import BenchConfig
from reconstruction.instrument.timing import (
    DXL_ACC_UNIT_REV_S2,
    DXL_UNITS_PER_REV,
    DXL_VEL_UNIT_REV_S,
    AxisTiming,
    MoveTiming,
    trapezoid_duration,
)
from reconstruction.schema.bench import Axis
from reconstruction.schema.simulator import SimulatorSection

__all__ = ["Point", "Reason", "Why", "point_key", "Geometry"]

Point = tuple[float, float]


class Reason(Enum):
    """Why a point cannot be measured."""

    OUTSIDE = "outside"                  # not within (-90, 90) degrees
    LIGHT_LIMIT = "light arm limits"     # beyond the light arm's soft limits
    DETECTOR_LIMIT = "detector arm limits"
    COLLISION = "collision"              # the arms would collide
    BLIND_SPOT = "blind spot"            # the source arm shadows the detector

    @property
    def unreachable(self) -> bool:
        """True for reasons that make a point unreachable (limits), False for collision / blind spot."""
        return self in (Reason.OUTSIDE, Reason.LIGHT_LIMIT, Reason.DETECTOR_LIMIT)


class Why(str):
    """The one-line explanation of an unmeasurable point (a ``str``, as it is logged and stored) with its
    :class:`Reason` as ``reason``."""

    reason: Reason

    def __new__(cls, text: str, reason: Reason) -> Why:
        w = super().__new__(cls, text)
        w.reason = reason
        return w

    def __getnewargs__(self) -> tuple[str, Reason]:  # type: ignore[override] # copies and pickles keep the reason
        return (str(self), self.reason)


#: Wall time (s) of one status query of the drivers' polling loop, and the capture software's own time per reading
#: (the commands around it, the sample converted, written and synced): what ``benchmarks/bench_time_model.py
#: --time-scale 1`` measures on the 2-core development machine. They count as bench time in real time (a real
#: bench, or a simulator with time_scale > 0), not when simulated time jumps.
QUERY_S = 0.0005
HOST_S_PER_READING = 0.004
#: the whole unit of each ``[bench].motion``'s arms, as messages name it
UNIT_NAMES = {"dynamixel": "servo units", "grbl": "steps", "serial": "controller units"}

#: The trapezoid of the shared time model (kept under its old name).
_trapezoid_time = trapezoid_duration


def point_key(p: Point) -> tuple[float, float]:
    """Hashable identity of a point: angles rounded to 1e-6 deg."""
    return (round(float(p[0]), 6) + 0.0, round(float(p[1]), 6) + 0.0)


@dataclass(frozen=True)
class Geometry:
    """What the bench can reach and how fast; angles in degrees, speeds in deg/s, accelerations in deg/s^2.

    Move times are the shared time model (:mod:`reconstruction.instrument.timing`, the one the simulator's axes move
    by):
    trapezoidal profiles of both arms at once between whole controller units, plus ``arrive_s`` during which the
    arms still report moving; the drivers poll for that every ``poll_s`` (bench time: ``[motion].poll_interval_s``
    plus a query, times the simulator's time scale; 0 when simulated time jumps), so a move is over at the first
    poll after it. ``settle_s`` is ``[motion].settle_s``, the wait before each reading; ``host_s`` the software's
    own bench time per reading (its queries, the slice written and synced; 0 when simulated time jumps)."""

    light: Axis
    detector: Axis
    min_separation_deg: float
    blind_spot_half_width_deg: float
    light_speed: tuple[float, float] = (math.inf, math.inf)
    detector_speed: tuple[float, float] = (math.inf, math.inf)
    settle_s: float = 0.0
    arrive_s: float = 0.0
    poll_s: float = 0.0
    host_s: float = 0.0
    coordinated: bool = False  # both arms on one straight line (GRBL), see reconstruction.instrument.timing
    units: str = "controller units"  # what a whole unit of the arms is called: "servo units", "steps"

    @classmethod
    def from_config(cls, cfg: BenchConfig) -> Geometry:
        """The geometry and time model of a bench file. On a simulated bench the simulated mechanics are the
        bench's: the time the arms report moving after a profile (``[simulator].settle_time_s``), the stepper
        profile (``[simulator].stepper_velocity_deg_s``, ``stepper_acceleration_deg_s2``) and the time scale
        (which turns the wall-clock polling interval into bench time)."""
        sim = _simulator_timing(cfg)
        speeds = []
        for ax in (cfg.light, cfg.det_axis):
            if cfg.bench.motion == "dynamixel":
                pv, pa = cfg.motion.profile_velocity, cfg.motion.profile_acceleration
                v = math.inf if pv <= 0 else pv * DXL_VEL_UNIT_REV_S * DXL_UNITS_PER_REV / ax.units_per_deg
                a = math.inf if pa <= 0 else pa * DXL_ACC_UNIT_REV_S2 * DXL_UNITS_PER_REV / ax.units_per_deg
            elif sim is not None:
                v, a = sim["stepper_velocity_deg_s"], sim["stepper_acceleration_deg_s2"]
            else:
                v, a = cfg.motion.velocity_deg_s, cfg.motion.acceleration_deg_s2
            speeds.append((v, a))
        scale = 1.0 if sim is None else sim["time_scale"]
        grbl = cfg.bench.motion == "grbl"  # one G0 line for both arms, Idle at its end ($110/$120 = [motion]'s)
        arrive = 0.0 if sim is None or grbl else sim["settle_time_s"]
        return cls(cfg.light, cfg.det_axis, cfg.bench.min_separation_deg, cfg.bench.blind_spot_half_width_deg,
                   speeds[0], speeds[1], cfg.motion.settle_s, arrive, (cfg.motion.poll_interval_s + QUERY_S) * scale,
                   HOST_S_PER_READING * scale, grbl, UNIT_NAMES.get(cfg.bench.motion, "controller units"))

    @cached_property
    def timing(self) -> MoveTiming:
        """The shared move-time model of the two arms (:class:`reconstruction.instrument.timing.MoveTiming`)."""
        def axis(ax: Axis, speed: tuple[float, float]) -> AxisTiming:
            upd = abs(ax.units_per_deg)
            return AxisTiming(ax.units_per_deg, ax.zero_offset, ax.direction, speed[0] * upd, speed[1] * upd)

        return MoveTiming(axis(self.light, self.light_speed), axis(self.detector, self.detector_speed),
                          self.arrive_s, self.coordinated)

    @property
    def park(self) -> Point:
        return (self.light.park_deg, self.detector.park_deg)

    def reason(self, ti: float, to: float) -> Why | None:
        """Why (ti, to) cannot be measured (a :class:`Why`: text and :class:`Reason`), or None if it can."""
        if not -90.0 < ti < 90.0 or not -90.0 < to < 90.0:
            return Why("outside (-90, 90) degrees", Reason.OUTSIDE)
        if not self.light.within(ti):
            return Why(f"theta_i {ti:g} outside the light arm soft limits "
                       f"[{self.light.min_deg:g}, {self.light.max_deg:g}] ([axes.light].min_deg, max_deg)",
                       Reason.LIGHT_LIMIT)
        if not self.detector.within(to):
            return Why(f"theta_o {to:g} outside the detector arm soft limits "
                       f"[{self.detector.min_deg:g}, {self.detector.max_deg:g}] ([axes.detector].min_deg, max_deg)",
                       Reason.DETECTOR_LIMIT)
        sep = abs(self.quantise(self.light, ti) + self.quantise(self.detector, to))  # at the goals as sent
        if sep < self.min_separation_deg:
            # the planned angles, and where whole controller units put the arms when that differs (a point planned
            # exactly min_separation_deg apart may fall short by a fraction of a unit: it is refused, and says why)
            planned = abs(ti + to)
            sent = f" ({sep:.3f} at the goals sent, in whole {self.units})" if abs(planned - sep) > 5e-4 else ""
            return Why(f"collision: arms {planned:g} deg apart{sent}, closer than min_separation_deg "
                       f"{self.min_separation_deg:g}", Reason.COLLISION)
        if sep < self.blind_spot_half_width_deg:
            return Why(f"blind spot: the source arm shadows the detector (|theta_i + theta_o| = {sep:.3f} < "
                       f"{self.blind_spot_half_width_deg:g})", Reason.BLIND_SPOT)
        return None

    def reasons(self, points: np.ndarray) -> list[Why | None]:
        """:meth:`reason` for many points (N, 2) at once (vectorised; strings only for the unmeasurable ones)."""
        pts = np.asarray(points, dtype=float).reshape(-1, 2)
        ti, to = pts[:, 0], pts[:, 1]
        lt, dt = self.light, self.detector
        outside = ~((np.abs(ti) < 90.0) & (np.abs(to) < 90.0))
        off_light = ~((ti >= lt.min_deg - 1e-9) & (ti <= lt.max_deg + 1e-9))
        off_det = ~((to >= dt.min_deg - 1e-9) & (to <= dt.max_deg + 1e-9))
        with np.errstate(all="ignore"):
            q_ti = (np.round(lt.zero_offset + lt.direction * lt.units_per_deg * ti) - lt.zero_offset) / (
                lt.direction * lt.units_per_deg)
            q_to = (np.round(dt.zero_offset + dt.direction * dt.units_per_deg * to) - dt.zero_offset) / (
                dt.direction * dt.units_per_deg)
            sep = np.abs(q_ti + q_to)
        bad = outside | off_light | off_det | (sep < self.min_separation_deg) | (
            sep < self.blind_spot_half_width_deg)
        out: list[Why | None] = [None] * len(pts)
        for k in np.flatnonzero(bad):
            out[k] = self.reason(float(ti[k]), float(to[k]))
        return out

    @staticmethod
    def quantise(ax: Axis, deg: float) -> float:
        """The angle the axis is actually sent to: ``deg`` rounded to whole controller units."""
        return ax.units_to_deg(round(ax.deg_to_units(deg)))

    @staticmethod
    def is_limit_reason(reason: str) -> bool:
        """True for reasons that make a point unreachable (limits), False for collision / blind spot."""
        if isinstance(reason, Why):
            return reason.reason.unreachable
        return reason.startswith(("theta_i", "theta_o", "outside"))  # a reason read back from a file

    def move_times(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Move time (s) between points ``a`` and ``b`` (..., 2), both arms moving at once, until they report in
        position (the shared model, plus the polling delay); without ``settle_s``."""
        t = self.timing.move_times(a, b)
        return np.ceil(t / self.poll_s - 1e-9) * self.poll_s if self.poll_s else t

    def move_time(self, a: Point, b: Point) -> float:
        """:meth:`move_times` of one move (plain floats)."""
        t = self.timing.move_time((float(a[0]), float(a[1])), (float(b[0]), float(b[1])))
        return math.ceil(t / self.poll_s - 1e-9) * self.poll_s if self.poll_s else t




def _simulator_timing(cfg: BenchConfig) -> dict[str, Any] | None:
    """The simulated mechanics of a simulated bench (``[simulator]`` keys with the schema's defaults; the
    simulator itself checks the section strictly), or None for a real bench."""
    if cfg.bench.transport != "simulated":
        return None
    raw = cfg.raw.get("simulator")
    raw = raw if isinstance(raw, dict) else {}
    defaults = SimulatorSection()
    out: dict[str, Any] = {}
    for key in ("settle_time_s", "stepper_velocity_deg_s", "stepper_acceleration_deg_s2", "time_scale"):
        v = raw.get(key)
        ok = isinstance(v, (int, float)) and not isinstance(v, bool) and math.isfinite(v) and v >= 0
        out[key] = float(v) if ok else float(getattr(defaults, key))
    return out
