"""A dry-run bench: the device protocols without devices, for ``gonio-capture --check`` and the estimate a capture
logs before it starts. The very plan of the capture's points (:func:`acquisition.plans.measure`) runs on it
through the same engine: every move is checked against the limits, and the time model accumulates (trapezoidal
moves of both arms at once, settling, ``repeats`` x the integration time per reading), so the estimate and the
capture cannot disagree about what the plan does. Nothing is opened or moved.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from .calibration import Reading
from .engine import Engine
from .errors import PlanError
from .messages import Move
from .plan import TWO_OPT_MAX_EVALUATIONS, Geometry, Plan, Point, path_time
from .plans import measure
from .protocols import Devices, MoveStatus

__all__ = ["DryRunBench", "dry_run", "estimate"]


class DryRunBench:
    """Axes, detector and clock of a bench that does not move: see the module docstring. ``now()`` is the
    modelled bench time (s) since the start; ``motion_s``, ``settle_s``, ``read_s`` its parts; ``moves`` the
    goals in order."""

    channels = ["value"]
    saturation = math.inf

    def __init__(self, geometry: Geometry, integration_time_s: float, start: Point | None = None) -> None:
        self.geometry = geometry
        self.integration_time_s = integration_time_s
        self.start: Point = geometry.park if start is None else start
        self.moves: list[Point] = []
        self.settle_s = self.read_s = 0.0
        self._zero = Reading(np.zeros(1), np.zeros(1), 1)
        self._status = MoveStatus(True, True, self.start)

    # -- Axes ----------------------------------------------------------------------------------------------------
    def set(self, theta_i_deg: float, theta_o_deg: float) -> MoveStatus:
        """Record the move; its limits and time are evaluated for all moves at once (:meth:`check`,
        :attr:`motion_s`)."""
        self.moves.append((theta_i_deg, theta_o_deg))
        return self._status

    def check(self) -> None:
        """Raise :class:`PlanError` for the first move beyond the soft limits (vectorised over all moves)."""
        if not self.moves:
            return
        for (ti, to), why in zip(self.moves, self.geometry.reasons(np.asarray(self.moves)), strict=True):
            if why is not None and why.reason.unreachable:
                raise PlanError(f"refusing to move to ({ti:g}, {to:g}): {why}")

    @property
    def motion_s(self) -> float:
        """Modelled time of every move so far (s): trapezoidal profiles of both arms at once."""
        if not self.moves:
            return 0.0
        seq = np.array([self.start, *self.moves], dtype=float)
        return float(self.geometry.move_times(seq[:-1], seq[1:]).sum())

    def check_value(self, theta_i_deg: float, theta_o_deg: float) -> str | None:
        return self.geometry.reason(theta_i_deg, theta_o_deg)

    def positions(self) -> Point:
        return self.moves[-1] if self.moves else self.start

    def stop(self) -> None:
        pass

    # -- Detector ------------------------------------------------------------------------------------------------
    def read(self, n: int) -> Reading:
        self.read_s += n * self.integration_time_s
        return self._zero

    dark = read

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


def dry_run(plan_gen: Any, geometry: Geometry, integration_time_s: float, start: Point | None = None
            ) -> DryRunBench:
    """Run any plan (a generator of :mod:`acquisition.messages`) on a :class:`DryRunBench` from ``start``
    (default: park): a :class:`PlanError` for a move beyond the soft limits; the bench returned holds the moves and
    the modelled times (``motion_s``, ``settle_s``, ``read_s``, ``now()``)."""
    bench = DryRunBench(geometry, integration_time_s, start)
    Engine(bench.devices(), settle_s=geometry.settle_s, retries=0, account=False).run(plan_gen)
    bench.check()
    return bench


def estimate(plan: Plan, geometry: Geometry, integration_time_s: float, points: Sequence[Point] | None = None,
             max_evaluations: int = TWO_OPT_MAX_EVALUATIONS) -> dict[str, float]:
    """Estimated times (s) of measuring ``points`` (default: the plan's measurable ones) as the capture does,
    from the park position and back: ``motion_s`` in the plan's order, ``naive_motion_s`` in the given order,
    ``total_s`` with settling and the detector, and ``points``. The plan's own points plan
    (:func:`~acquisition.plans.measure`) runs on a :class:`DryRunBench`, which refuses moves beyond the limits."""
    pts = plan.check(geometry).measurable if points is None else list(points)

    def points_then_park() -> Any:
        yield from measure(pts, geometry, plan.repeats, None, plan.order, max_evaluations)
        yield Move(*geometry.park, checkpoint=False)  # back to park, as a capture ends

    bench = dry_run(points_then_park(), geometry, integration_time_s)
    return {"points": float(len(pts)), "motion_s": bench.motion_s, "naive_motion_s": path_time(pts, geometry),
            "total_s": bench.now()}
