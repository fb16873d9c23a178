"""Capture plans as data: the points to measure, checked before anything moves, ordered for short arm travel.

A point is ``(theta_i_deg, theta_o_deg)``: light arm at theta_i, detector arm at the signed theta_o (positive on
the specular side). :class:`Geometry` knows what the bench can reach (soft limits), where the arms would
collide (``|theta_i + theta_o| < min_separation_deg``) and where the source arm shadows the detector (the blind
spot, ``|theta_i + theta_o| < blind_spot_half_width_deg``), and how long a move takes (trapezoidal profiles of
both arms moving at once; :mod:`acquisition.plans.geometry`). :meth:`Plan.check` sorts points into measurable and
unmeasurable ones, each with its reason (a :class:`Why`: the text and a :class:`Reason`): nothing is dropped
silently. :func:`order_points` (:mod:`acquisition.plans.ordering`) orders them to minimise travel time. What a capture
does with a plan is itself a plan, a generator of messages: :mod:`acquisition.plans`.

Scenes (``configs/scenes/*.toml``, :mod:`reconstruction.core.scene`) restrict a plan to what a scene needs: see
:meth:`Plan.restrict`.
"""

from __future__ import annotations

import hashlib
import json
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import msgspec
import numpy as np

from acquisition.errors import ConfigError, PlanError
from acquisition.plans.geometry import Geometry, Point, point_key
from acquisition.plans.ordering import TWO_OPT_MAX_EVALUATIONS
from acquisition.plans.planconfig import MAX_PLAN_POINTS, _count, _frange, resolution_deg
from reconstruction.core.scene import CAPTURE_DEFAULT_RANGE_DEG, Scene, SceneError
from reconstruction.core.scene import load_scene as _load_scene
from reconstruction.schema.bench import AdaptiveTable, PlanTable

__all__ = ["Plan", "PlanCheck", "load_scene"]

# --- scenes ----------------------------------------------------------------------------------------------------

#: theta_i and theta_o range (degrees) of a scene whose file gives none, for a capture: the whole hemisphere (one
#: definition beside the reconstruction's, which differs on purpose: reconstruction.core.scene).
SCENE_DEFAULT_RANGE_DEG = CAPTURE_DEFAULT_RANGE_DEG


def load_scene(path: str | Path) -> Scene:
    """Read and validate a scene file (:func:`reconstruction.core.scene.load_scene`); errors are :class:`ConfigError`
    (the message names the file and the key), as for bench configs."""
    try:
        return _load_scene(path)  # the one user-file check (type, size, UTF-8) is inside it
    except SceneError as e:
        raise ConfigError(str(e)) from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read the scene file ({e.strerror or e})") from None
    except RecursionError:
        raise ConfigError(f"{path}: invalid TOML: nested too deeply") from None


# --- plans -----------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Sweep:
    """One incidence with an outgoing range: theta_o from ``lo`` to ``hi`` every ``step`` degrees."""

    theta_i_deg: float
    lo: float
    hi: float
    step: float

    def points(self, step: float | None = None) -> list[Point]:
        s = self.step if step is None else step
        tos = _frange(self.lo, self.hi, s)
        if tos and abs(tos[-1] - self.hi) > 1e-6:
            tos.append(round(self.hi, 9))  # always include the end of the range
        return [(self.theta_i_deg, to) for to in tos]


@dataclass
class PlanCheck:
    """Result of :meth:`Plan.check`: measurable points and unmeasurable ones with their reasons."""

    measurable: list[Point]
    unmeasurable: list[tuple[float, float, str]]

    @property
    def unreachable(self) -> list[tuple[float, float, str]]:
        """Points outside the soft limits (a plan error, unlike collision / blind-spot points)."""
        return [u for u in self.unmeasurable if Geometry.is_limit_reason(u[2])]

    def describe(self, limit: int = 8) -> str:
        """The counts, then the unmeasurable points grouped by incidence and reason (runs of theta_o), at most
        ``limit`` lines of them: ``theta_i 40, theta_o -46 to -34 (7 points): collision: ...``; a point alone
        as ``(ti, to): why``."""
        lines = [f"{len(self.measurable)} measurable points, {len(self.unmeasurable)} not measurable"]
        groups = group_unmeasurable(self.unmeasurable, self.measurable)
        lines += [f"  {g}" for g in groups[:limit]]
        if len(groups) > limit:
            lines.append(f"  ... and {len(groups) - limit} more groups")
        return "\n".join(lines)


#: what makes a reason's text specific to one point, and its general form (a group's)
_GENERAL = ((re.compile(r"arms [\d.]+ deg apart( \([\d.]+ at the goals sent, in whole [a-z ]+\))?, closer than "
                        r"(min_separation_deg \S+)"), r"arms closer than \2 (at the goals sent)"),
            (re.compile(r"= [\d.]+ <"), "<"), (re.compile(r"^theta_([io]) \S+ outside"), r"theta_\1 outside"))


def _general(why: str) -> str:
    for pattern, repl in _GENERAL:
        why = pattern.sub(repl, why)
    return why


def scene_changes(base: Plan, fitted: Plan) -> str:
    """One line: what fitting ``base`` to a scene (:meth:`Plan.restrict`) did: the incidences it kept, the theta_o
    ranges, the step (the scene's angular resolution, which adds points when it is finer than the plan's), and the
    points before and after."""
    n0, n1 = len(base.requested_points()), len(fitted.requested_points())
    parts = []
    if base.sweeps and fitted.sweeps:
        inc0 = sorted({sw.theta_i_deg for sw in base.sweeps})
        inc1 = sorted({sw.theta_i_deg for sw in fitted.sweeps})
        parts.append(f"incidences {', '.join(f'{t:g}' for t in inc1)} of {', '.join(f'{t:g}' for t in inc0)}")
        ranges = sorted({(sw.lo, sw.hi) for sw in fitted.sweeps})
        parts.append("theta_o " + " and ".join(f"{round(lo, 1):g} to {round(hi, 1):g}" for lo, hi in ranges))
        s0, s1 = min(sw.step for sw in base.sweeps), min(sw.step for sw in fitted.sweeps)
        if s1 < s0:
            parts.append(f"step {s1:g} deg, finer than the plan's {s0:g} (the scene's angular_resolution_deg): "
                         "it adds points")
        elif s1 > s0:
            parts.append(f"step {s1:g} deg instead of the plan's {s0:g} (the scene's angular_resolution_deg)")
    more = "more" if n1 > n0 else "fewer" if n1 < n0 else "as many"
    return f"scene {fitted.scene!r}: {'; '.join(parts)}: {n1} points, {more} than the plan's {n0}"


def group_unmeasurable(points: Sequence[tuple[float, float, str]], measurable: Sequence[Point] = ()) -> list[str]:
    """Unmeasurable points as lines in order of incidence and theta_o: one per run of theta_o at one incidence with
    one reason (in its general form) and no other plan point (``measurable``, or another reason) between them."""
    at: dict[float, list[tuple[float, str | None]]] = {}
    for ti, to in measurable:
        at.setdefault(float(ti), []).append((float(to), None))
    for ti, to, why in points:
        at.setdefault(float(ti), []).append((float(to), str(why)))
    out: list[str] = []

    def flush(ti: float, run: list[tuple[float, str]]) -> None:
        if len(run) == 1:
            out.append(f"({ti:g}, {run[0][0]:g}): {run[0][1]}")
        elif run:
            out.append(f"theta_i {ti:g}, theta_o {run[0][0]:g} to {run[-1][0]:g} ({len(run)} points): "
                       f"{_general(run[0][1])}")

    for ti in sorted(at):
        run: list[tuple[float, str]] = []
        for to, why in sorted(at[ti], key=lambda p: p[0]):
            if why is not None and run and _general(why) == _general(run[0][1]):
                run.append((to, why))
                continue
            flush(ti, run)
            run = [] if why is None else [(to, why)]
        flush(ti, run)
    return out


@dataclass
class Plan:
    """Points to measure, with repeats and options. Build with :meth:`grid`, :meth:`from_points` or
    :meth:`from_config`; restrict with :meth:`restrict`; check with :meth:`check`.

    With ``adaptive`` set, :meth:`initial_points` is the coarse pass and the capture adds midpoints where the slice
    changes fast (:func:`refine_points`) down to ``adaptive.min_step_deg``.
    """

    sweeps: list[Sweep] = field(default_factory=list)
    explicit: list[Point] | None = None
    repeats: int = 4
    dark_at_end: bool = True
    order: str = "optimized"
    strict: bool = False
    adaptive: AdaptiveTable | None = None
    scene: str | None = None

    @classmethod
    def grid(cls, theta_i_deg: Iterable[float], theta_o_min_deg: float, theta_o_max_deg: float,
             theta_o_step_deg: float, **kw: Any) -> Plan:
        """Every incidence with theta_o from min to max (inclusive) every step degrees."""
        if theta_o_step_deg <= 0:
            raise PlanError(f"theta_o_step_deg must be > 0, got {theta_o_step_deg:g}")
        if theta_o_max_deg < theta_o_min_deg:
            raise PlanError(f"theta_o_max_deg {theta_o_max_deg:g} < theta_o_min_deg {theta_o_min_deg:g}")
        sweeps = [Sweep(float(ti), float(theta_o_min_deg), float(theta_o_max_deg), float(theta_o_step_deg))
                  for ti in theta_i_deg]
        return cls(sweeps=sweeps, **kw)

    @classmethod
    def from_points(cls, points: Iterable[Sequence[float]], **kw: Any) -> Plan:
        """An explicit list of (theta_i_deg, theta_o_deg) points."""
        return cls(explicit=[(float(p[0]), float(p[1])) for p in points], **kw)

    @classmethod
    def from_config(cls, pc: PlanTable, base_dir: Path | str = ".") -> Plan:
        """The ``[plan]`` of a bench file; a ``scene`` key there is applied with :meth:`restrict`."""
        kw = dict(repeats=pc.repeats, dark_at_end=pc.dark_at_end, order=pc.order, strict=pc.strict,
                  adaptive=pc.adaptive)
        if pc.points is not None:
            plan = cls.from_points(pc.points, **kw)
        else:
            assert pc.theta_o_min_deg is not None and pc.theta_o_max_deg is not None
            assert pc.theta_o_step_deg is not None
            plan = cls.grid(pc.theta_i_deg, pc.theta_o_min_deg, pc.theta_o_max_deg, pc.theta_o_step_deg, **kw)
        if pc.scene:
            p = Path(pc.scene)
            if not p.is_absolute():
                p = Path(base_dir) / p
            plan = plan.restrict(load_scene(p))
        return plan

    def restrict(self, scene: Scene) -> Plan:
        """This plan limited to what ``scene`` needs: the plan's incidences within the scene's theta_i range;
        outgoing angles whose polar angle |theta_o| lies in the scene's theta_o range (both sides of the normal),
        within the plan's range; the scene's angular resolution as the step; its error budget (relative_rmse) as
        the adaptive tolerance."""
        (ti_lo, ti_hi), (to_lo, to_hi) = scene.ranges(SCENE_DEFAULT_RANGE_DEG)

        def keep_ti(ti: float) -> bool:
            return ti_lo - 1e-9 <= abs(ti) <= ti_hi + 1e-9

        if self.explicit is not None:
            pts = [p for p in self.explicit if keep_ti(p[0]) and to_lo - 1e-9 <= abs(p[1]) <= to_hi + 1e-9]
            if not pts:
                raise PlanError(f"{scene.source}: scene {scene.name!r} keeps none of the plan's points")
            return replace(self, explicit=pts, scene=scene.name)
        if not self.sweeps:
            raise PlanError("the plan is empty")
        sweeps = []
        for sw in self.sweeps:
            if not keep_ti(sw.theta_i_deg):
                continue
            step = scene.angular_resolution_deg or sw.step
            sides = [(-to_hi, -to_lo), (to_lo, to_hi)] if to_lo > 0 else [(-to_hi, to_hi)]
            for a, b in sides:
                lo, hi = max(sw.lo, a), min(sw.hi, b)
                if hi >= lo:
                    sweeps.append(Sweep(sw.theta_i_deg, lo, hi, step))
        if not sweeps:
            raise PlanError(f"{scene.source}: scene {scene.name!r} (theta_i in [{ti_lo:g}, {ti_hi:g}], |theta_o| in "
                            f"[{to_lo:g}, {to_hi:g}]) keeps none of the plan's points")
        adaptive = self.adaptive
        if adaptive is not None:
            res = scene.angular_resolution_deg
            adaptive = msgspec.structs.replace(
                adaptive,
                tolerance=scene.relative_rmse if scene.relative_rmse is not None else adaptive.tolerance,
                min_step_deg=min(adaptive.min_step_deg, res) if res else adaptive.min_step_deg,
                coarse_step_deg=max(adaptive.coarse_step_deg, res) if res else adaptive.coarse_step_deg)
        return replace(self, sweeps=sweeps, adaptive=adaptive, scene=scene.name)

    def requested_points(self) -> list[Point]:
        """Every point the plan asks for (without adaptive refinement), deduplicated, in naive order."""
        if self.explicit is not None:
            pts = list(self.explicit)
        elif self.adaptive is not None:
            pts = [p for s in self.sweeps for p in s.points(self.adaptive.coarse_step_deg)]
        else:
            pts = [p for s in self.sweeps for p in s.points()]
        if not pts:
            return []
        arr = np.asarray(pts, dtype=float).reshape(-1, 2)
        keys = np.round(arr, 6) + 0.0  # point_key of every point at once
        _, first = np.unique(keys, axis=0, return_index=True)
        return [(float(a), float(b)) for a, b in arr[np.sort(first)]]

    initial_points = requested_points

    def check(self, geom: Geometry) -> PlanCheck:
        """Sort the requested points into measurable and unmeasurable (with reasons)."""
        pts = self.requested_points()
        ok, bad = [], []
        for p, why in zip(pts, geom.reasons(np.array(pts, dtype=float).reshape(-1, 2)), strict=True):
            if why is None:
                ok.append(p)
            else:
                bad.append((p[0], p[1], why))
        return PlanCheck(ok, bad)

    def size(self) -> float:
        """How many points the plan can grow to, computed without building them: the requested points, or with
        adaptive refinement (and no ``max_points``) the number at its ``min_step_deg``. A float (may be huge)."""
        if self.explicit is not None:
            return float(len(self.explicit))
        a = self.adaptive
        if a is not None:
            worst = sum(_count(s.lo, s.hi, a.min_step_deg) for s in self.sweeps)
            return float(min(worst, a.max_points)) if a.max_points else float(worst)
        return float(sum(_count(s.lo, s.hi, s.step) for s in self.sweeps))

    def check_size(self, geom: Geometry) -> None:
        """Raise :class:`PlanError` for a step finer than the detector axis can make or for a plan larger than
        :data:`~acquisition.plans.planconfig.MAX_PLAN_POINTS`; runs before any point is built."""
        res = resolution_deg(geom.detector)
        steps = [("theta_o step", s.step) for s in self.sweeps]
        if self.adaptive is not None:
            steps += [("adaptive coarse_step_deg", self.adaptive.coarse_step_deg),
                      ("adaptive min_step_deg", self.adaptive.min_step_deg)]
        scene = f" (from scene {self.scene!r})" if self.scene else ""
        for what, step in steps:
            if not step >= res * (1 - 1e-9):
                raise PlanError(f"the plan's {what} of {step:g} deg{scene} is finer than the detector axis "
                                f"resolution of {res:.4g} deg (1 / units_per_deg)")
        n = self.size()
        if n > MAX_PLAN_POINTS:
            raise PlanError(f"the plan{scene} has {n:.3g} points, more than the {MAX_PLAN_POINTS} a plan may hold; "
                            "use a coarser step, fewer incidences or (adaptive) max_points")

    def validate(self, geom: Geometry) -> PlanCheck:
        """:meth:`check`, raising :class:`PlanError` for a plan beyond the axes' resolution or the point limit
        (:meth:`check_size`), for points outside the soft limits (or, with ``strict``, for any unmeasurable point)
        and for a plan with nothing to measure."""
        self.check_size(geom)
        chk = self.check(geom)
        bad = chk.unmeasurable if self.strict else chk.unreachable
        if bad:
            lines = "\n".join(f"  ({ti:g}, {to:g}): {why}" for ti, to, why in bad[:10])
            more = f"\n  ... and {len(bad) - 10} more" if len(bad) > 10 else ""
            raise PlanError(f"{len(bad)} plan point(s) cannot be measured:\n{lines}{more}")
        if not chk.measurable:
            raise PlanError("the plan has no measurable point")
        return chk

    def to_meta(self) -> dict[str, Any]:
        """JSON description of the plan (stored in the slice metadata; a resume must match it)."""
        d: dict[str, Any] = {"repeats": self.repeats, "order": self.order}
        if self.explicit is not None:
            d["points"] = [list(p) for p in self.explicit]
        else:
            d["sweeps"] = [[s.theta_i_deg, s.lo, s.hi, s.step] for s in self.sweeps]
        if self.adaptive is not None:
            a = self.adaptive
            d["adaptive"] = {"coarse_step_deg": a.coarse_step_deg, "min_step_deg": a.min_step_deg,
                             "tolerance": a.tolerance, "time_budget_s": a.time_budget_s,
                             "max_points": a.max_points, "max_rounds": a.max_rounds}
        if self.scene:
            d["scene"] = self.scene
        return d

    def fingerprint(self) -> str:
        """Short hash of the points and repeats (what a resume must agree on)."""
        key = {"points": [list(point_key(p)) for p in self.requested_points()], "repeats": self.repeats,
               "adaptive": self.to_meta().get("adaptive")}
        return hashlib.sha256(json.dumps(key, sort_keys=True).encode()).hexdigest()[:16]

    def estimate(self, geom: Geometry, integration_time_s: float, points: Sequence[Point] | None = None,
                 max_evaluations: int = TWO_OPT_MAX_EVALUATIONS, cfg: Any = None) -> dict[str, float]:
        """Estimated times (s): ``motion_s`` in this plan's order, ``naive_motion_s`` in naive order, and
        ``total_s`` with settle and detector time: the capture's own plan of the points run on a dry-run bench
        (:func:`acquisition.run.dryrun.estimate`). ``max_evaluations``: the 2-opt budget of the ordering (a smaller one
        gives the same order for plans of up to about a thousand points, and a slightly longer estimate for bigger
        ones, faster). With the bench file ``cfg``: the whole capture (calibration, points, final dark) and its
        parts."""
        from acquisition.run.dryrun import estimate

        return estimate(self, geom, integration_time_s, points, max_evaluations, cfg=cfg)
