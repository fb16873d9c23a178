"""Motion of one axis in simulated time: trapezoidal profile, stall, settling and backlash.

Units are the axis' controller units (Dynamixel position units or stepper steps) and simulated seconds. A
profile's duration and the settling after it are the shared time model (:mod:`reconstruction.instrument.timing`), the
one the planner's estimate adds up.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from reconstruction.instrument.timing import dxl_profile_units, trapezoid_duration

#: Dynamixel X-series unit conversions.
DXL_DEG_PER_UNIT = 360.0 / 4096.0            # 0.088 deg per position unit
DXL_RPM_PER_VEL_UNIT = 0.229                 # Profile Velocity unit, rev/min
DXL_RPM2_PER_ACC_UNIT = 214.577              # Profile Acceleration unit, rev/min^2

#: Dynamixel Profile Velocity/Acceleration -> (units/s, units/s^2); 0 means unlimited (``inf``): the shared model's.
dxl_profile_to_units = dxl_profile_units


@dataclass
class TrapezoidProfile:
    """Point-to-point move from ``x0`` to ``x1`` starting at ``t0``, limited by ``v_max`` and ``a_max``.

    ``inf`` for ``v_max`` and/or ``a_max`` gives rectangular / triangular / instantaneous profiles like the
    Dynamixel firmware (0 = unlimited there).
    """

    x0: float
    x1: float
    t0: float
    v_max: float = math.inf
    a_max: float = math.inf

    def __post_init__(self) -> None:
        d = abs(self.x1 - self.x0)
        self._sign = 1.0 if self.x1 >= self.x0 else -1.0
        self._d = d
        v, a = self.v_max, self.a_max
        self.duration = float(trapezoid_duration(d, v, a))  # the shared model's (reconstruction.instrument.timing)
        if d == 0 or (math.isinf(v) and math.isinf(a)):
            self._t_acc, self._t_flat, self._v_peak = 0.0, 0.0, math.inf
            self.duration = 0.0
        elif math.isinf(a):
            self._t_acc, self._t_flat, self._v_peak = 0.0, self.duration, v
        elif math.isinf(v) or d < v * v / a:
            t_acc = 0.5 * self.duration
            self._t_acc, self._t_flat, self._v_peak = t_acc, 0.0, a * t_acc
        else:
            t_acc = v / a
            self._t_acc, self._t_flat, self._v_peak = t_acc, self.duration - 2 * t_acc, v

    @property
    def t_end(self) -> float:
        return self.t0 + self.duration

    def distance(self, t: np.ndarray | float) -> np.ndarray | float:
        """Unsigned distance travelled by time ``t`` (vectorised)."""
        t = np.asarray(t, dtype=float)
        if self.duration == 0.0:
            out = np.where(t >= self.t0, self._d, 0.0)
            return out if out.ndim else float(out)
        tau = np.clip(t - self.t0, 0.0, self.duration)
        ta, tf, vp = self._t_acc, self._t_flat, self._v_peak
        a = vp / ta if ta > 0 else math.inf
        d_acc = 0.5 * vp * ta
        t2 = ta + tf
        s1 = 0.5 * a * tau**2 if ta > 0 else np.zeros_like(tau)
        s2 = d_acc + vp * (tau - ta)
        td = self.duration - tau
        s3 = self._d - (0.5 * a * td**2 if ta > 0 else 0.0)
        out = np.where(tau < ta, s1, np.where(tau < t2, s2, s3))
        return out if out.ndim else float(out)

    def position(self, t: np.ndarray | float) -> np.ndarray | float:
        """Position (units) at time ``t`` (vectorised)."""
        return self.x0 + self._sign * self.distance(t)

    def velocity(self, t: float) -> float:
        """Signed velocity (units/s) at time ``t``."""
        tau = t - self.t0
        if tau < 0 or tau >= self.duration or self.duration == 0:
            return 0.0
        ta, tf, vp = self._t_acc, self._t_flat, self._v_peak
        if tau < ta:
            v = vp * tau / ta
        elif tau < ta + tf:
            v = vp
        else:
            v = vp * (self.duration - tau) / ta if ta > 0 else vp
        return self._sign * v


class AxisMotion:
    """Motor and arm of one axis.

    ``motor_position`` is what an encoder/step counter reports; ``arm_position`` is where the arm physically is:
    it lags the motor through a dead band of ``backlash`` units and rings with a decaying oscillation of
    ``ringing`` units during ``settle_time`` after a profile ends. A stall freezes the motor partway (the
    profile never completes).
    """

    def __init__(self, position: float, *, backlash: float = 0.0, ringing: float = 0.0,
                 settle_time: float = 0.0) -> None:
        self.backlash = float(backlash)
        self.ringing = float(ringing)
        self.settle_time = float(settle_time)
        self.profile = TrapezoidProfile(position, position, -1e9)
        self._arm0 = float(position)  # arm position at the start of the current profile
        self.stall_time: float | None = None
        self.frozen_at: float | None = None  # motor stopped (torque off / STOP) at this time

    # -- motor -------------------------------------------------------------------------------------------
    def motor_position(self, t: float) -> float:
        if self.frozen_at is not None:
            t = min(t, self.frozen_at)
        if self.stall_time is not None:
            t = min(t, self.stall_time)
        return float(self.profile.position(t))

    def motor_velocity(self, t: float) -> float:
        if (self.frozen_at is not None and t >= self.frozen_at) or (
            self.stall_time is not None and t >= self.stall_time
        ):
            return 0.0
        return self.profile.velocity(t)

    @property
    def goal(self) -> float:
        return self.profile.x1

    def profiling(self, t: float) -> bool:
        """True while the profile runs (forever when stalled, never once frozen)."""
        if self.frozen_at is not None and t >= self.frozen_at:
            return False
        if self.stall_time is not None:
            return True
        return t < self.profile.t_end

    def settled_time(self) -> float:
        """Simulated time at which the motion including settling is over (``inf`` if stalled)."""
        if self.frozen_at is not None:
            return self.frozen_at
        if self.stall_time is not None:
            return math.inf
        return self.profile.t_end + (self.settle_time if self.profile.duration > 0 else 0.0)

    def moving(self, t: float) -> bool:
        """True during the profile and its settle time."""
        return t < self.settled_time()

    # -- arm ---------------------------------------------------------------------------------------------
    def arm_position(self, t: float) -> float:
        m = self.motor_position(t)
        half = 0.5 * self.backlash
        arm = min(max(self._arm0, m - half), m + half)
        if self.ringing and self.settle_time > 0 and self.stall_time is None and self.frozen_at is None:
            te = self.profile.t_end
            dt = t - te
            if self.profile.duration > 0 and 0 <= dt < self.settle_time:
                tau = self.settle_time / 4.0
                freq = 3.0 / self.settle_time
                sign = 1.0 if self.profile.x1 >= self.profile.x0 else -1.0
                arm += sign * self.ringing * math.exp(-dt / tau) * math.cos(2 * math.pi * freq * dt)
        return arm

    # -- commands ----------------------------------------------------------------------------------------
    def start(self, goal: float, t: float, v_max: float, a_max: float, stall_fraction: float | None = None) -> None:
        """Start a move to ``goal`` at time ``t`` from the current motor position (stops any running move)."""
        x0 = self.motor_position(t)
        half = 0.5 * self.backlash
        self._arm0 = min(max(self._arm0_at(t), x0 - half), x0 + half)
        self.frozen_at = None
        self.stall_time = None
        self.profile = TrapezoidProfile(x0, float(goal), t, v_max, a_max)
        if stall_fraction is not None and self.profile.duration > 0:
            self.stall_time = t + stall_fraction * self.profile.duration

    def _arm0_at(self, t: float) -> float:
        m = self.motor_position(t)
        half = 0.5 * self.backlash
        return min(max(self._arm0, m - half), m + half)

    def stop(self, t: float) -> None:
        """Stop the motor where it is at ``t`` (torque off, emergency stop); no settling."""
        x = self.motor_position(t)
        self._arm0 = self._arm0_at(t)
        self.profile = TrapezoidProfile(x, x, t)
        self.stall_time = None
        self.frozen_at = None
