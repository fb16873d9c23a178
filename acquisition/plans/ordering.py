"""Ordering plan points for short arm travel: serpentine and nearest-neighbour tours improved by 2-opt, within a
fixed work budget (deterministic: the same points give the same order on any machine and under any load).
"""

from __future__ import annotations

import hashlib
from collections.abc import Sequence
from typing import Any

import numpy as np

from acquisition.plans.geometry import Geometry, Point

__all__ = ["path_time", "order_points", "TWO_OPT_MAX_EVALUATIONS"]


def path_time(points: Sequence[Point], geom: Geometry, start: Point | None = None, end: Point | None = None
              ) -> float:
    """Total move time (s) visiting ``points`` in order, from ``start`` and back to ``end`` (default: park)."""
    start = geom.park if start is None else start
    end = geom.park if end is None else end
    seq = np.array([start, *points, end], dtype=float)
    if len(seq) < 2:
        return 0.0
    return float(geom.move_times(seq[:-1], seq[1:]).sum())


def _serpentine(points: Sequence[Point], geom: Geometry, start: Point, reverse_ti: bool) -> list[Point]:
    groups: dict[float, list[Point]] = {}
    for p in points:
        groups.setdefault(p[0], []).append(p)
    out: list[Point] = []
    cur = start
    for ti in sorted(groups, reverse=reverse_ti):
        g = sorted(groups[ti], key=lambda p: p[1])
        if geom.move_time(cur, g[-1]) < geom.move_time(cur, g[0]):
            g.reverse()
        out += g
        cur = g[-1]
    return out


def _nearest_neighbour(pts: np.ndarray, geom: Geometry, start: Point) -> list[int]:
    n = len(pts)
    left = np.ones(n, dtype=bool)
    cur = np.asarray(start, dtype=float)
    order = []
    for _ in range(n):
        t = geom.move_times(cur[None, :], pts)
        t[~left] = np.inf
        k = int(np.argmin(t))
        order.append(k)
        left[k] = False
        cur = pts[k]
    return order


#: Work budget of the 2-opt improvement in :func:`order_points`: candidate segment reversals evaluated (about
#: 0.5 s of computing on a 2-core machine). A count, not a clock, so the order does not depend on machine load.
TWO_OPT_MAX_EVALUATIONS = 4_000_000


def _two_opt(seq: np.ndarray, geom: Geometry, max_evaluations: int) -> np.ndarray:
    """2-opt on a path with fixed first and last nodes (``seq`` (N, 2)); stops when no reversal gains or after
    ``max_evaluations`` candidate reversals were evaluated (deterministic: the same input gives the same path)."""
    n = len(seq)
    if n < 5:
        return seq
    seq = seq.copy()
    evaluations = 0
    improved = True
    while improved and evaluations < max_evaluations:
        improved = False
        for i in range(0, n - 3):
            a, b = seq[i], seq[i + 1]
            c = seq[i + 2:n - 1]
            d = seq[i + 3:n]
            gain = (geom.move_time(a, b) + geom.move_times(c, d)
                    - geom.move_times(a[None, :], c) - geom.move_times(b[None, :], d))
            evaluations += len(c)
            k = int(np.argmax(gain))
            if gain[k] > 1e-9:
                j = i + 2 + k
                seq[i + 1:j + 1] = seq[i + 1:j + 1][::-1].copy()
                improved = True
            if evaluations >= max_evaluations:
                break
    return seq


def order_points(points: Sequence[Point], geom: Geometry, start: Point | None = None,
                 end: Point | None = None, max_evaluations: int = TWO_OPT_MAX_EVALUATIONS) -> list[Point]:
    """Order ``points`` to minimise the total move time from ``start`` to ``end`` (default: park).

    Tries serpentine orders (incidence by incidence, alternating the outgoing sweep) and a nearest-neighbour
    tour, improves the best with 2-opt (at most ``max_evaluations`` candidate reversals), and returns the
    fastest. Deterministic: the same points give the same order on any machine and under any load.
    """
    start = geom.park if start is None else tuple(start)
    end = geom.park if end is None else tuple(end)
    pts = [tuple(map(float, p)) for p in points]
    if len(pts) <= 1:
        return list(pts)  # type: ignore[arg-type]
    key = (hashlib.sha256(np.asarray(pts, dtype=float).tobytes()).digest(), start, end, max_evaluations, geom)
    hit = _ORDERED.get(key)
    if hit is not None:  # the same points ordered a moment ago (the estimate before a capture, then the capture)
        return list(hit)
    best = _order(pts, geom, start, end, max_evaluations)
    _ORDERED[key] = tuple(best)
    while len(_ORDERED) > 8:
        _ORDERED.pop(next(iter(_ORDERED)))
    return best


#: The last few orders computed by :func:`order_points` (deterministic, so they can be reused).
_ORDERED: dict[Any, tuple[Point, ...]] = {}


def _order(pts: list[Any], geom: Geometry, start: Any, end: Any, max_evaluations: int) -> list[Point]:
    """The work of :func:`order_points`: serpentine and nearest-neighbour candidates, the best improved by 2-opt."""
    cands = [_serpentine(pts, geom, start, False), _serpentine(pts, geom, start, True)]
    arr = np.array(pts)
    if len(pts) <= 3000:
        cands.append([pts[k] for k in _nearest_neighbour(arr, geom, start)])
    best = min(cands, key=lambda s: path_time(s, geom, start, end))
    full = np.array([start, *best, end], dtype=float)
    improved = _two_opt(full, geom, max_evaluations)[1:-1]
    improved_list = [(float(x), float(y)) for x, y in improved]
    if path_time(improved_list, geom, start, end) < path_time(best, geom, start, end):
        best = improved_list
    return best


