"""A dry-run bench: the device protocols without devices, for ``gonio-capture --check`` and the estimate a capture
logs before it starts. The very plan of the capture (:func:`acquisition.plans.capture`: the dark level and the
white reference, the points in the capture's order from where the capture starts them, the final dark) runs on it
through the same engine, which accounts its times as in a capture: every move is checked against the limits and
the time model accumulates (the shared move-time model of :mod:`reconstruction.instrument.timing`, by which the
simulator's axes move, plus the polling delay; ``[motion].settle_s`` per point; ``repeats`` x the integration
time per reading), so the estimate and the capture cannot disagree about what the plan does. Nothing is opened or
moved. Auto-ranging: the darks at every gain are part of the calibration plan, so they are counted; every reading
is counted on the setting it needs, which the capture's first reading of a point predicts from its neighbours
(:meth:`acquisition.devices.autorange.AutoRanger.predict`); what the estimate cannot foresee, the sample being
unknown, is the readings of a mispredicted setting (the white reference's probe, the first point of an incidence, a
peak's edge: ``auto_range_overhead_s`` of the result, about 0.5 % of the demo's bench time) and the shorter
integration times of a sample brighter than the lowest gain holds (counted at the configured time: the estimate is
then long).
Adaptive refinement's rounds are estimated as they are planned.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from acquisition.calibration import Calibration, Reading
from acquisition.config import BenchConfig
from acquisition.devices.protocols import Devices, MoveStatus
from acquisition.errors import PlanError
from acquisition.plans.generators import CaptureContext, PlanSpec, PointsPlan, capture, last_recorded, measure
from acquisition.plans.geometry import Geometry, Point, point_key
from acquisition.plans.ordering import TWO_OPT_MAX_EVALUATIONS, path_time
from acquisition.run.engine import Engine
from acquisition.run.record import CaptureResult

__all__ = ["DryRunBench", "dry_run", "estimate", "estimate_points"]


class DryRunBench:
    """Axes, detector and clock of a bench that does not move: see the module docstring. ``now()`` is the
    modelled bench time (s) since the start; ``motion_s``, ``settle_s``, ``read_s`` its parts; ``moves`` the
    goals in order. Readings are 1 count with the source on and 0 dark (a white reference that reads a signal)."""

    channels = ["value"]
    saturation = math.inf

    def __init__(self, geometry: Geometry, integration_time_s: float, start: Point | None = None) -> None:
        self.geometry = geometry
        self.integration_time_s = integration_time_s
        # the arms at park as a bench reads them back (whole controller units), so that a capture that asks where
        # they are before its first move orders its points from the same place as its estimate
        park = (geometry.quantise(geometry.light, geometry.park[0]), geometry.quantise(geometry.detector,
                                                                                      geometry.park[1]))
        self.start: Point = park if start is None else start
        self.moves: list[Point] = []
        self.motion_s = self.settle_s = self.read_s = 0.0
        self._pos = self.start
        self._one = Reading(np.ones(1), np.zeros(1), 1, monitor=1.0)  # a monitor too: ratio readings' plans
        self._zero = Reading(np.zeros(1), np.zeros(1), 1, monitor=1.0)
        self._status = MoveStatus(True, True, self.start)

    # -- Axes ----------------------------------------------------------------------------------------------------
    def set(self, theta_i_deg: float, theta_o_deg: float) -> MoveStatus:
        """Record the move and its modelled time; its limits are checked for all moves at once (:meth:`check`)."""
        goal = (theta_i_deg, theta_o_deg)
        self.motion_s += self.geometry.move_time(self._pos, goal)
        self._pos = goal
        self.moves.append(goal)
        return self._status

    def check(self) -> None:
        """Raise :class:`PlanError` for the first move beyond the soft limits (vectorised over all moves)."""
        if not self.moves:
            return
        for (ti, to), why in zip(self.moves, self.geometry.reasons(np.asarray(self.moves)), strict=True):
            if why is not None and why.reason.unreachable:
                raise PlanError(f"refusing to move to ({ti:g}, {to:g}): {why}")

    def check_value(self, theta_i_deg: float, theta_o_deg: float) -> str | None:
        return self.geometry.reason(theta_i_deg, theta_o_deg)

    def positions(self) -> Point:
        return self._pos

    def stop(self) -> None:
        pass

    # -- Detector ------------------------------------------------------------------------------------------------
    def read(self, n: int) -> Reading:
        self.read_s += n * self.integration_time_s + self.geometry.host_s
        return self._one

    def dark(self, n: int) -> Reading:
        self.read_s += n * self.integration_time_s + self.geometry.host_s
        return self._zero

    def set_integration_time(self, seconds: float) -> float:
        self.integration_time_s = seconds
        return seconds

    def set_sample(self, which: str) -> None:
        pass

    def describe(self) -> dict[str, Any]:
        return {"type": "dry run", "integration_time_s": self.integration_time_s}

    # -- Clock ---------------------------------------------------------------------------------------------------
    def now(self) -> float:
        return self.motion_s + self.settle_s + self.read_s

    def dwell(self, seconds: float) -> None:
        self.settle_s += seconds

    def devices(self) -> Devices:
        return Devices(self, self, self)  # type: ignore[arg-type]


def dry_run(plan_gen: Any, geometry: Geometry, integration_time_s: float, start: Point | None = None,
            result: CaptureResult | None = None) -> DryRunBench:
    """Run any plan (a generator of :mod:`acquisition.plans.messages`) on a :class:`DryRunBench` from ``start``
    (default: park): a :class:`PlanError` for a move beyond the soft limits; the bench returned holds the moves and
    the modelled times (``motion_s``, ``settle_s``, ``read_s``, ``now()``). ``result``: the engine accounts the
    times there as in a capture (motion, settle and read of the points)."""
    bench = DryRunBench(geometry, integration_time_s, start)
    Engine(bench.devices(), settle_s=geometry.settle_s, retries=0, result=result, account=result is not None,
           convert=False).run(plan_gen)
    bench.check()
    return bench


@contextmanager
def _quiet() -> Iterator[None]:
    """The plans' log lines are not written while a dry run plays them (the capture's log holds what happened)."""
    lg = logging.getLogger("acquisition.plans")
    was = lg.disabled
    lg.disabled = True
    try:
        yield
    finally:
        lg.disabled = was


def _dry_calibration(cfg: BenchConfig) -> Calibration:
    one, zero = Reading(np.ones(1), np.zeros(1), 1), Reading(np.zeros(1), np.zeros(1), 1)
    return Calibration("relative", zero, one, np.ones(1), cfg.calibration.reference_theta_o_deg or 0.0)


def estimate(plan: PlanSpec, geometry: Geometry, integration_time_s: float, points: Sequence[Point] | None = None,
             max_evaluations: int = TWO_OPT_MAX_EVALUATIONS, cfg: BenchConfig | None = None,
             points_plan: PointsPlan | None = None, done: Sequence[Point] = (), calibrated: bool = False,
             ) -> dict[str, float]:
    """Estimated bench times (s) of capturing ``points`` (default: the plan's measurable ones).

    With the bench file ``cfg``: the whole capture plan as the capture runs it (:func:`~acquisition.plans.capture`
    with ``points_plan``, default :func:`~acquisition.plans.measure` with ``max_evaluations``): ``calibration_s``
    (dark level, white reference with its move, final dark), the points from where the capture starts them
    (``motion_s`` in the plan's order, ``naive_motion_s`` in the given order, ``settle_s``, ``read_s``) and
    ``total_s``, what the capture's ``bench_time_s`` measures (parking afterwards is ``park_s``, not in it).
    ``done``: points already in the slice (a resume), ``calibrated``: the calibration comes from the slice.
    Without ``cfg``: only the points, from park and back (as before). Adaptive refinement is not in it (its rounds
    are estimated as they are planned, :func:`estimate_points`); auto-ranging is as the module docstring says.
    A :class:`PlanError` for a move beyond the soft limits."""
    pts = plan.check(geometry).measurable if points is None else list(points)
    res = CaptureResult("", "")

    def own_points(ctx: CaptureContext, p: Sequence[Point]) -> Any:
        yield from measure(p, ctx.geometry, ctx.plan.repeats, ctx.done, ctx.plan.order, max_evaluations)

    if cfg is None:
        def points_then_park() -> Any:
            yield from measure(pts, geometry, plan.repeats, None, plan.order, max_evaluations)
            yield from _park(geometry)

        with _quiet():
            bench = dry_run(points_then_park(), geometry, integration_time_s, result=res)
        return {"points": float(len(pts)), "motion_s": bench.motion_s, "naive_motion_s": path_time(pts, geometry),
                "total_s": bench.now()}
    have = {point_key(p) for p in done}
    todo = [p for p in pts if point_key(p) not in have]
    ctx = CaptureContext(cfg, plan, geometry, pts, {point_key(p): (p[0], p[1], 0.0, 0.0) for p in done},
                         _dry_calibration(cfg) if calibrated else None, np.ones(1), 0.0, points_plan or own_points,
                         estimate_points, last_recorded(done) if calibrated else [])
    bench = DryRunBench(geometry, integration_time_s)
    with _quiet():
        Engine(bench.devices(), settle_s=geometry.settle_s, retries=0, result=res, account=True,
               convert=False).run(capture(ctx))
    total = bench.now()
    end = bench.positions()
    park = geometry.move_time(end, geometry.park)
    bench.check()
    start = _start_of_points(cfg, geometry, calibrated)
    return {"points": float(len(todo)), "motion_s": res.motion_s,
            "naive_motion_s": path_time(todo, geometry, start, todo[-1] if todo else start),
            "settle_s": res.settle_s, "read_s": res.read_s,
            "calibration_s": total - res.motion_s - res.settle_s - res.read_s, "total_s": total, "park_s": park}


def _park(geometry: Geometry) -> Any:
    from acquisition.plans.messages import Move

    yield Move(*geometry.park, checkpoint=False)  # back to park, as a capture ends


def _start_of_points(cfg: BenchConfig, geometry: Geometry, calibrated: bool) -> Point:
    """Where the arms are when the capture's points start: at the white reference (relative calibration of a new
    capture), else at park."""
    c = cfg.calibration
    if calibrated or c.mode != "relative" or c.reference_theta_i_deg is None or c.reference_theta_o_deg is None:
        return DryRunBench(geometry, 0.0).start
    return (c.reference_theta_i_deg, c.reference_theta_o_deg)


def estimate_points(ctx: CaptureContext, points: Sequence[Point], start: Point, integration_time_s: float
                    ) -> float:
    """Estimated bench time (s) of measuring ``points`` with the capture's points plan from ``start``: a round of
    adaptive refinement as it is planned (on a copy of the samples, nothing of ``ctx`` changes)."""
    from dataclasses import replace

    dry_ctx = replace(ctx, done=dict(ctx.done))
    bench = DryRunBench(ctx.geometry, integration_time_s, start)
    with _quiet():
        Engine(bench.devices(), settle_s=ctx.geometry.settle_s, retries=0, account=False, convert=False).run(
            ctx.points_plan(dry_ctx, points))
    return bench.now()
