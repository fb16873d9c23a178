"""The ``[plan]`` and ``[plan.adaptive]`` tables of a bench file, read against their schema
(:class:`reconstruction.schema.bench.PlanTable`) and bounded before any point is built: a step finer than the axis
resolution or a plan of more than :data:`MAX_PLAN_POINTS` points (adaptive refinement counted at its worst) is a
:class:`~acquisition.errors.ConfigError` naming the key. Angles in degrees.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

from acquisition.errors import ConfigError
from reconstruction.schema import SchemaError, Table
from reconstruction.schema.bench import AdaptiveTable, Axis, DetectorTable, PlanTable

__all__ = ["MAX_PLAN_POINTS", "read_plan", "resolution_deg"]

#: A plan may hold at most this many points (incidences x outgoing angles, or the adaptive refinement's worst
#: case): bigger plans are a config error, not a capture of days. That is more than a full 1 x 1 degree in-plane
#: grid (86 x 177 points), about 6 hours at 1 s per point on a real bench; ``gonio-capture --check`` prints the
#: size and estimated time of any plan within it in under a second.
MAX_PLAN_POINTS = 20_000


class _Table(Table):
    """One table of the bench file read against its schema (used by :mod:`acquisition.config` too); errors are
    :class:`ConfigError` naming ``file: [section].key``."""

    def __init__(self, source: str, section: str, raw: Any, cls: type, **kw: Any) -> None:
        try:
            super().__init__(source, section, raw, cls, **kw)
        except SchemaError as e:
            raise ConfigError(str(e)) from None

    def error(self, key: str, text: str) -> ConfigError:  # type: ignore[override]
        return ConfigError(f"{self.source}: [{self.section}].{key}: {text}")


def resolution_deg(ax: Axis) -> float:
    """The smallest angle step (deg) an axis can make: one controller unit."""
    return 1.0 / ax.units_per_deg


def _count(lo: float, hi: float, step: float) -> float:
    """Number of angles ``lo, lo + step, ... <= hi`` plus the end (as :func:`_frange` and the plan make them),
    computed without building them (a float: may be astronomically large)."""
    return math.floor((hi - lo) / step + 1e-9) + 2.0


def _finer_than_axis(src: str, section: str, key: str, step: float, ax: Axis) -> None:
    res = resolution_deg(ax)
    if step < res * (1 - 1e-9):
        raise ConfigError(f"{src}: [{section}].{key}: {step:g} deg is finer than the {ax.name} axis resolution of "
                          f"{res:.4g} deg (1 / [axes.{ax.name}].units_per_deg = 1 / {ax.units_per_deg:g}); no "
                          "position between two controller units can be reached")


def _read_adaptive(src: str, raw: Any, step: float | None) -> AdaptiveTable:
    t = _Table(src, "plan.adaptive", raw, AdaptiveTable)
    coarse = t["coarse_step_deg"] if t["coarse_step_deg"] is not None else (4 * step if step else None)
    if coarse is None:
        raise t.error("coarse_step_deg", "missing key (no theta_o_step_deg to derive it from)")
    if t["min_step_deg"] > coarse:
        raise t.error("min_step_deg", f"{t['min_step_deg']:g} is larger than coarse_step_deg {coarse:g}")
    return t.build(coarse_step_deg=coarse)


def read_plan(src: str, raw: Any, det: DetectorTable, axes: Mapping[str, Axis]) -> PlanTable:
    """``[plan]`` (and ``[plan.adaptive]``) read and bounded: the struct with ``theta_i_deg`` resolved (from the
    list, or from theta_i_min/max/step), ``repeats`` defaulting to ``[detector].repeats`` and ``adaptive`` None when
    left out or disabled (its ``coarse_step_deg`` resolved)."""
    adaptive_raw = raw.get("adaptive") if isinstance(raw, Mapping) else None
    t = _Table(src, "plan", raw, PlanTable, defaults={"repeats": det.repeats}, skip=("adaptive",))
    ti: list[float] = []
    if t["theta_i_deg"] is not None:
        if any(t.given(k) for k in ("theta_i_min_deg", "theta_i_max_deg", "theta_i_step_deg")):
            raise t.error("theta_i_min_deg", "give either theta_i_deg (a list) or theta_i_min_deg/max/step, "
                                             "not both")
        ti = t["theta_i_deg"]
    elif any(t.given(k) for k in ("theta_i_min_deg", "theta_i_max_deg", "theta_i_step_deg")):
        for k in ("theta_i_min_deg", "theta_i_max_deg", "theta_i_step_deg"):
            if t[k] is None:
                raise t.error(k, "missing key (theta_i_min_deg, theta_i_max_deg and theta_i_step_deg go "
                                 "together)")
        if t["theta_i_max_deg"] < t["theta_i_min_deg"]:
            raise t.error("theta_i_max_deg", "must be >= theta_i_min_deg")
        _finer_than_axis(src, "plan", "theta_i_step_deg", t["theta_i_step_deg"], axes["light"])
        n = _count(t["theta_i_min_deg"], t["theta_i_max_deg"], t["theta_i_step_deg"])
        if n > MAX_PLAN_POINTS:
            raise t.error("theta_i_step_deg", f"{n:.3g} incidences, more than a plan may hold "
                                              f"({MAX_PLAN_POINTS} points); use a coarser step")
        ti = _frange(t["theta_i_min_deg"], t["theta_i_max_deg"], t["theta_i_step_deg"])
    for x in ti:
        if not -90 < x < 90:
            raise t.error("theta_i_deg", f"incidence {x:g} is outside (-90, 90) degrees")
    has_range = any(t.given(k) for k in ("theta_o_min_deg", "theta_o_max_deg", "theta_o_step_deg"))
    if t["points"] is None:
        if not ti:
            raise t.error("theta_i_deg", "missing key: the incidence angles (or an explicit points list)")
        for k in ("theta_o_min_deg", "theta_o_max_deg", "theta_o_step_deg"):
            if t[k] is None:
                raise t.error(k, "missing key: the outgoing range and step")
        if t["theta_o_max_deg"] < t["theta_o_min_deg"]:
            raise t.error("theta_o_max_deg", f"{t['theta_o_max_deg']:g} is less than theta_o_min_deg "
                                             f"{t['theta_o_min_deg']:g}")
        _finer_than_axis(src, "plan", "theta_o_step_deg", t["theta_o_step_deg"], axes["detector"])
        n = len(ti) * _count(t["theta_o_min_deg"], t["theta_o_max_deg"], t["theta_o_step_deg"])
        if n > MAX_PLAN_POINTS:
            raise t.error("theta_o_step_deg", f"the plan would have {n:.3g} points ({len(ti)} incidence(s) x "
                                              f"{n / len(ti):.3g} outgoing angles), more than the {MAX_PLAN_POINTS} "
                                              "a plan may hold; use a coarser step or fewer incidences")
    elif ti or has_range:
        raise t.error("points", "give either an explicit points list or theta_i_deg with a theta_o range, "
                                "not both")
    if t["points"] is not None and len(t["points"]) > MAX_PLAN_POINTS:
        raise t.error("points", f"{len(t['points'])} points, more than the {MAX_PLAN_POINTS} a plan may hold")
    adaptive = None
    if adaptive_raw is not None:
        adaptive = _read_adaptive(src, adaptive_raw, t["theta_o_step_deg"])
        for key in ("coarse_step_deg", "min_step_deg"):
            if adaptive.enabled:
                _finer_than_axis(src, "plan.adaptive", key, getattr(adaptive, key), axes["detector"])
        if ti and t["theta_o_min_deg"] is not None and adaptive.enabled:
            worst = len(ti) * _count(t["theta_o_min_deg"], t["theta_o_max_deg"], adaptive.min_step_deg)
            if worst > MAX_PLAN_POINTS and not 0 < adaptive.max_points <= MAX_PLAN_POINTS:
                raise ConfigError(f"{src}: [plan.adaptive].min_step_deg: the refinement could reach {worst:.3g} "
                                  f"points ({len(ti)} incidence(s) at {adaptive.min_step_deg:g} deg), more than the "
                                  f"{MAX_PLAN_POINTS} a plan may hold; set max_points (at most {MAX_PLAN_POINTS}) "
                                  "or a coarser min_step_deg")
        if t["points"] is not None and adaptive.enabled:
            raise ConfigError(f"{src}: [plan.adaptive].enabled: adaptive refinement needs a theta_o range, "
                              "not an explicit points list")
        if not adaptive.enabled:
            adaptive = None
    return t.build(theta_i_deg=tuple(ti), points=tuple(t["points"]) if t["points"] is not None else None,
                   adaptive=adaptive)


def _frange(lo: float, hi: float, step: float) -> list[float]:
    """``lo, lo + step, ... <= hi`` (inclusive within 1e-9), rounded to 1e-9 deg."""
    n = int(math.floor((hi - lo) / step + 1e-9))
    return [round(lo + k * step, 9) for k in range(n + 1)]


