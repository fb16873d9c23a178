"""Adaptive refinement's rule: where a measured in-plane slice changes fast, the midpoints to measure next
(:func:`refine_points`). Angles in degrees.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from acquisition.plans.geometry import Geometry, Point, point_key

__all__ = ["refine_points"]


def refine_points(samples: Mapping[float, Sequence[tuple[float, float, float]]], geom: Geometry,
                  tolerance: float, min_step_deg: float, measured: set[tuple[float, float]] | None = None
                  ) -> list[Point]:
    """Midpoints to add where a slice changes fast.

    ``samples`` maps theta_i to (theta_o, value, std) triples (value: the sample's mean over channels). For
    each gap between neighbouring theta_o the interpolation error of the piecewise-linear slice is estimated
    from the second differences at its ends (``h^2 |f''| / 8``, less three standard deviations of what the
    noise alone contributes to it) and compared with ``tolerance`` times the local level (floored at three
    times the noise and 1 % of the slice maximum). A jump between neighbours larger than twice the tolerance
    (beyond three sigma of noise) also splits the gap, so that a narrow peak between two coarse samples is
    found. Gaps whose estimate exceeds the tolerance get their midpoint, unless that would make a gap narrower
    than ``min_step_deg`` or the midpoint cannot be measured. Computed for all gaps of a slice at once (numpy).
    Deterministic: the same samples give the same points.
    """
    measured = set() if measured is None else measured
    out: list[Point] = []
    for ti in sorted(samples):
        rows = sorted(samples[ti])
        if len(rows) < 2:
            continue
        x = np.array([r[0] for r in rows])
        v = np.array([r[1] for r in rows])
        s = np.array([r[2] for r in rows])
        vmax = float(np.max(np.abs(v))) if len(v) else 0.0
        n = len(x)
        # second differences at the inner samples, normalised to a uniform spacing (divided difference times h^2)
        d2 = np.zeros(n)
        h1, h2 = x[1:-1] - x[:-2], x[2:] - x[1:-1]
        d2[1:-1] = np.abs(2.0 * ((v[2:] - v[1:-1]) / h2 - (v[1:-1] - v[:-2]) / h1) / (h1 + h2))
        # per gap k (between samples k and k + 1)
        h = x[1:] - x[:-1]
        curv = np.maximum(d2[:-1], d2[1:])  # all 0 with two samples
        # noise of the values entering the estimate: max std over samples k - 1 .. k + 2 (those that exist)
        s_pad = np.concatenate(([-np.inf], s, [-np.inf, -np.inf]))
        sig = np.lib.stride_tricks.sliding_window_view(s_pad, 4)[: n - 1].max(axis=1)
        # max error of linear interpolation on the gap, less what noise alone would produce (3 sigma of the
        # second difference, sqrt(6) sigma / h^2 for equal gaps)
        err = np.maximum(curv * h * h / 8.0 - 3.0 * math.sqrt(6.0) * sig / 8.0, 0.0)
        jump = np.abs(v[1:] - v[:-1])
        noise = 3.0 * np.maximum(s[:-1], s[1:])
        level = np.maximum(np.maximum(0.5 * (np.abs(v[:-1]) + np.abs(v[1:])), noise), max(0.01 * vmax, 1e-300))
        split = (h / 2.0 >= min_step_deg - 1e-9) & (np.maximum(err, 0.5 * jump - noise) / level > tolerance)
        for k in np.flatnonzero(split):
            mid = (float(ti), round(0.5 * (x[k] + x[k + 1]), 9))
            if point_key(mid) in measured or geom.reason(*mid) is not None:
                continue
            out.append(mid)
    return out
