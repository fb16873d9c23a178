"""The bench's motion-time model, in one place: the simulator's axes (``simulator.world.motion``) move by it and the
planner's estimate (``acquisition.plans.geometry``, ``acquisition.run.dryrun``) adds it up, so the two cannot disagree.

A move of an axis is a rest-to-rest trapezoidal profile between whole controller units (the goal is rounded as the
drivers send it) at the profile's speed ``v`` and acceleration ``a`` (units/s, units/s^2; ``inf`` = unlimited, as
Dynamixel's 0), followed by ``arrive_s`` of mechanical settling during which the axis still reports moving (the
servo's Moving flag, the stepper controller's ``state=Moving``; ``[simulator].settle_time_s`` on the simulator).
Both arms start together, so a move lasts as long as its slower arm; an arm that does not move costs nothing.

This module is pure (numpy only) and imports nothing of the project, so the simulator, the acquisition and the
reconstruction may all use it (the import contracts of ``pyproject.toml``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

__all__ = ["DXL_VEL_UNIT_REV_S", "DXL_ACC_UNIT_REV_S2", "DXL_UNITS_PER_REV", "dxl_profile_units", "trapezoid_duration",
           "AxisTiming", "MoveTiming", "line_durations"]

#: Dynamixel X-series profile units: Profile Velocity 0.229 rev/min, Profile Acceleration 214.577 rev/min^2.
DXL_VEL_UNIT_REV_S = 0.229 / 60.0
DXL_ACC_UNIT_REV_S2 = 214.577 / 3600.0
DXL_UNITS_PER_REV = 4096.0


def dxl_profile_units(profile_velocity: int, profile_acceleration: int) -> tuple[float, float]:
    """Dynamixel Profile Velocity / Acceleration (their register units) -> (units/s, units/s^2) of the position
    register; 0 means unlimited (``inf``), as in the firmware."""
    v = math.inf if profile_velocity <= 0 else profile_velocity * DXL_VEL_UNIT_REV_S * DXL_UNITS_PER_REV
    a = math.inf if profile_acceleration <= 0 else profile_acceleration * DXL_ACC_UNIT_REV_S2 * DXL_UNITS_PER_REV
    return v, a


def trapezoid_duration(d: np.ndarray | float, v: float, a: float) -> np.ndarray:
    """Duration (s) of rest-to-rest moves over distances ``d`` (any shape, same units as ``v`` and ``a``) at top
    speed ``v`` and acceleration ``a`` (``inf``: rectangular, triangular or instantaneous profiles)."""
    d = np.abs(np.asarray(d, dtype=float))
    if math.isinf(v) and math.isinf(a):
        return np.zeros_like(d)
    if math.isinf(a):
        return d / v
    if math.isinf(v):
        return 2.0 * np.sqrt(d / a)
    d_ramp = v * v / a
    return np.where(d < d_ramp, 2.0 * np.sqrt(d / a), d / v + v / a)


@dataclass(frozen=True)
class AxisTiming:
    """One axis as the time model sees it: ``units = zero_offset + direction * units_per_deg * deg`` (rounded to
    whole units when sent), profile limits ``v`` (units/s) and ``a`` (units/s^2)."""

    units_per_deg: float
    zero_offset: float = 0.0
    direction: int = 1
    v: float = math.inf
    a: float = math.inf

    def units(self, deg: np.ndarray | float) -> np.ndarray:
        """Whole controller units the drivers send for angles ``deg`` (any shape)."""
        return np.round(self.zero_offset + self.direction * self.units_per_deg * np.asarray(deg, dtype=float))

    def duration(self, a_deg: float, b_deg: float) -> float:
        """:meth:`durations` of one move, in plain floats (fast: a dry run of 20,000 points calls it per move)."""
        k = self.direction * self.units_per_deg
        d = abs(round(self.zero_offset + k * b_deg) - round(self.zero_offset + k * a_deg))
        v, a = self.v, self.a
        if d == 0 or (math.isinf(v) and math.isinf(a)):
            return 0.0
        if math.isinf(a):
            return d / v
        if math.isinf(v) or d < v * v / a:
            return 2.0 * math.sqrt(d / a)
        return d / v + v / a

    def durations(self, a_deg: np.ndarray | float, b_deg: np.ndarray | float) -> np.ndarray:
        """Profile durations (s) of moves from ``a_deg`` to ``b_deg`` (broadcast), between whole units."""
        return trapezoid_duration(self.units(b_deg) - self.units(a_deg), self.v, self.a)


def line_durations(d1: np.ndarray, d2: np.ndarray, v: tuple[float, float], a: tuple[float, float]) -> np.ndarray:
    """Duration (s) of straight-line moves of two axes by ``d1``, ``d2`` units that start and arrive together, as
    GRBL's planner moves them: the line's speed and acceleration are the largest that keep each axis within its
    own ``v`` (units/s) and ``a`` (units/s^2). Per unit of the line's parameter s in [0, 1] an axis moving ``d``
    allows ``v / d`` and ``a / d``; the line is a trapezoid of length 1 at the smallest of them."""
    d = [np.abs(np.asarray(d1, dtype=float)), np.abs(np.asarray(d2, dtype=float))]
    with np.errstate(divide="ignore", invalid="ignore"):
        vs = np.minimum(*(np.where(d[i] > 0, v[i] / d[i], np.inf) for i in range(2)))
        acc = np.minimum(*(np.where(d[i] > 0, a[i] / d[i], np.inf) for i in range(2)))
        t = np.where(vs * vs / acc > 1.0, 2.0 * np.sqrt(1.0 / acc), 1.0 / vs + vs / acc)
    return np.where((d[0] > 0) | (d[1] > 0), np.nan_to_num(t, nan=0.0, posinf=0.0), 0.0)


@dataclass(frozen=True)
class MoveTiming:
    """Both arms (light, detector) of a bench and the time after a profile they still report moving
    (``arrive_s``). ``coordinated``: both arms move on one straight line and arrive together (GRBL: ``G0 X.. Y..``
    is one block), instead of each on its own profile (Dynamixel servos, the text-protocol controller)."""

    light: AxisTiming
    detector: AxisTiming
    arrive_s: float = 0.0
    coordinated: bool = False

    def move_times(self, a: np.ndarray, b: np.ndarray) -> np.ndarray:
        """Time (s) from sending the goals ``b`` (..., 2: theta_i, theta_o in degrees) with the arms at rest at
        ``a`` until both report in position and not moving: the slower arm's profile (or the line of both) plus
        ``arrive_s`` (0 when neither arm moves)."""
        a = np.asarray(a, dtype=float)
        b = np.asarray(b, dtype=float)
        if self.coordinated:
            L, D = self.light, self.detector
            t = line_durations(L.units(b[..., 0]) - L.units(a[..., 0]), D.units(b[..., 1]) - D.units(a[..., 1]),
                               (L.v, D.v), (L.a, D.a))
        else:
            tl = self.light.durations(a[..., 0], b[..., 0])
            td = self.detector.durations(a[..., 1], b[..., 1])
            t = np.maximum(tl, td)
        return np.where(t > 0.0, t + self.arrive_s, 0.0)

    def move_time(self, a: tuple[float, float], b: tuple[float, float]) -> float:
        """:meth:`move_times` of one move, in plain floats."""
        if self.coordinated:
            return float(self.move_times(np.asarray(a), np.asarray(b)))
        t = max(self.light.duration(a[0], b[0]), self.detector.duration(a[1], b[1]))
        return t + self.arrive_s if t > 0.0 else 0.0
