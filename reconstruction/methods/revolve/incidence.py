"""Incidence preparation for revolve: a slice split into cleaned, ordered curves, one per measured incidence, and
the thesis's merged solid of one of them (:func:`thesis_hemisphere`).

Blind-spot rows are dropped by the one rule the whole reconstruction shares,
:func:`reconstruction.formats.inputs.blind_spot_missing` (exact zeros at the retro direction, and the zero rows
contiguous
with them); negative values (dark-subtraction noise) are set to 0 first.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.base import ReconstructionError
from reconstruction.core.geometry import thesis_points_from_slice
from reconstruction.core.slicedata import Slice, channel_kind
from reconstruction.formats.inputs import DEFAULT_BLIND_SPOT_DEG, blind_spot_missing
from reconstruction.methods.revolve.thesis import (
    _AXIS_KINDS,
    _FLAT_RATIO,
    _LOBE_REACH,
    _LOG_FLOOR,
    DEFAULT_MIN_TURN_DEG,
    DEFAULT_SMOOTHING_DEG,
    Array,
    Axis,
    HemisphereMap,
    _split,
    merge_solids,
    revolve,
    subcurve_axis,
)


@dataclass
class _Incidence:
    """One measured incidence, cleaned: the ordered curve, its sub-curves, axes and lobe interpretations."""

    theta_i: float  # radians
    theta_o: Array  # (n,) radians, strictly increasing
    f: Array  # (n, C) f_r >= 0
    lum: Array  # (n,) channel sum
    hole_after: NDArray[np.bool_]  # (n - 1,) the gap after sample k is missing data
    n_removed: int  # blind-spot rows dropped
    n_clipped: int  # negative values set to 0
    holes_deg: list[tuple[float, float]] = field(default_factory=list)  # gaps of missing data, degrees
    ranges: list[tuple[int, int]] = field(default_factory=list)
    axes: list[Axis] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)
    peaks: list[float] = field(default_factory=list)
    tails: list[int] = field(default_factory=list)  # sub-curves joined to their lobe as its grazing tail


def _bridge_holes(inc: _Incidence) -> int:
    """Fill each hole of the curve with samples every nominal step (in place); returns how many were added.

    Log-linear between the hole's edges, unless the two samples on each side show a peak inside the hole
    (a concave log-quadratic fit, as a retro-reflection peak hidden in the blind spot): then that fit, at
    most twice the edges' larger value. Channels follow the luminance's shape.
    """
    holes = np.nonzero(inc.hole_after)[0]
    if holes.size == 0:
        return 0
    to, f, lum = inc.theta_o, inc.f, inc.lum
    step = float(np.median(np.diff(to)[~inc.hole_after])) if (~inc.hole_after).any() else float(np.diff(to).min())
    new_t, new_f = [], []
    for k in holes:  # a handful of holes
        m = int(math.ceil((to[k + 1] - to[k]) / step))
        tq = to[k] + (to[k + 1] - to[k]) * np.arange(1, m) / m
        if tq.size == 0:
            continue
        fq = _loglin(tq, to[k:k + 2], f[k:k + 2])
        nb = np.arange(k - 1, k + 3)
        if nb[0] >= 0 and nb[-1] < to.size and np.all(lum[nb] > 0) and not inc.hole_after[[k - 1, k + 1]].any():
            x = to[nb] - to[k]
            a2, a1, a0 = np.polyfit(x, np.log(lum[nb]), 2)
            if a2 < 0:
                lin = np.log(np.maximum(_loglin(tq, to[k:k + 2], lum[k:k + 2, None])[:, 0], _LOG_FLOOR))
                quad = np.minimum(a2 * (tq - to[k]) ** 2 + a1 * (tq - to[k]) + a0,
                                  math.log(2.0 * max(lum[k], lum[k + 1])))
                fq = fq * np.exp(np.maximum(quad - lin, 0.0))[:, None]
        new_t.append(tq)
        new_f.append(fq)
    if not new_t:
        return 0
    t_all = np.concatenate([to, *new_t])
    f_all = np.concatenate([f, *new_f])
    order = np.argsort(t_all, kind="stable")
    inc.theta_o, inc.f = t_all[order], f_all[order]
    inc.lum = inc.f.sum(axis=1)
    inc.hole_after = np.zeros(inc.theta_o.size - 1, dtype=bool)
    return int(t_all.size - to.size)


#: A neighbouring incidence may lend its specular peak to one whose mirror direction is unmeasured when it lies
#: within this many degrees of theta_i.
_LEND_MAX_DEG = 20.0


def _lend_peaks(incs: list[_Incidence]) -> list[str]:
    """Fill an incidence's hole over its own mirror direction (normal incidence: the mirror direction is the retro
    direction, inside the blind spot) with the nearest incidence's measured peak (in place); returns notes.

    The donor's samples keep their offset from its mirror direction and f cos(theta_i) cos(theta_o) (a
    microfacet lobe's measured shape barely changes over 10-20 deg of theta_i); they replace the hole's bridged
    samples only where the donor shows a peak more than twice as bright as the bridge (a missed specular peak).
    """
    notes: list[str] = []
    if len(incs) < 2:
        return notes

    def hole_over_mirror(inc: _Incidence) -> tuple[float, float] | None:
        t = math.degrees(inc.theta_i)
        return next(((a, b) for a, b in inc.holes_deg if a < t < b), None)

    donors = [inc for inc in incs if hole_over_mirror(inc) is None
              and np.min(np.abs(inc.theta_o - inc.theta_i)) < math.radians(1.0)]
    for inc in incs:  # a handful
        hole = hole_over_mirror(inc)
        if hole is None or not donors:
            continue
        donor = min(donors, key=lambda d: abs(d.theta_i - inc.theta_i))
        if abs(donor.theta_i - inc.theta_i) > math.radians(_LEND_MAX_DEG):
            continue
        lo, hi = math.radians(hole[0]), math.radians(hole[1])
        d = donor.theta_o - donor.theta_i
        take = (inc.theta_i + d > lo) & (inc.theta_i + d < hi)
        if not take.any():
            continue
        to_new = inc.theta_i + d[take]
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = (math.cos(donor.theta_i) * np.cos(donor.theta_o[take])) / (
                math.cos(inc.theta_i) * np.cos(to_new))
        f_new = donor.f[take] * np.where(np.isfinite(ratio), ratio, 0.0)[:, None]
        inside = (inc.theta_o > lo) & (inc.theta_o < hi)
        bridged = float(inc.lum[inside].max()) if inside.any() else float(max(inc.lum.min(), 0.0))
        if not f_new.sum(axis=1).max() > 2.0 * bridged:
            continue
        t_all = np.r_[inc.theta_o[~inside], to_new]
        f_all = np.vstack([inc.f[~inside], f_new])
        order = np.argsort(t_all, kind="stable")
        inc.theta_o, inc.f = t_all[order], f_all[order]
        inc.lum = inc.f.sum(axis=1)
        inc.hole_after = np.zeros(inc.theta_o.size - 1, dtype=bool)
        notes.append(f"theta_i {math.degrees(inc.theta_i):g} deg: the mirror direction is in the hole "
                     f"{hole} deg; the peak measured at theta_i {math.degrees(donor.theta_i):g} deg fills it "
                     f"({int(take.sum())} samples at the same offsets from the mirror direction)")
    return notes


def _prepare(slices: Slice, sort: bool, blind_spot_deg: float | None, bridge: bool = False
             ) -> tuple[list[_Incidence], list[str]]:
    """Validate a slice and split it into cleaned incidences; raise ReconstructionError on bad input.

    ``bridge``: fill holes (blind spot, missing samples) with interpolated samples (:func:`_bridge_holes`).
    """
    if not isinstance(slices, Slice):
        raise ReconstructionError(f"expected a reconstruction.core.slicedata.Slice, got {type(slices).__name__}")
    src = slices.source
    if len(slices) == 0:
        raise ReconstructionError(f"{src}: empty slice, no samples to revolve")
    try:
        kind = channel_kind(slices.channels)
    except ValueError as e:
        raise ReconstructionError(f"{src}: {e}") from None
    if kind == "spectral":
        raise ReconstructionError(f"{src}: spectral channels {slices.channels[:3]}...; convert the slice to "
                                  "linear RGB first (revolve reconstructs 1 grey or 3 RGB channels)")
    ti_all, to_all = slices.theta_i_deg, slices.theta_o_deg
    for name, arr in (("theta_i_deg", ti_all), ("theta_o_deg", to_all)):
        bad = ~np.isfinite(arr) | (np.abs(arr) >= 90.0)
        if bad.any():
            k = int(np.argmax(bad))
            raise ReconstructionError(f"{src}: sample {k}: {name} = {arr[k]} is not a finite angle in (-90, 90)")
    if np.any(ti_all < 0):
        k = int(np.argmax(ti_all < 0))
        raise ReconstructionError(f"{src}: sample {k}: theta_i_deg = {ti_all[k]} < 0; the light is on the -x "
                                  "side at theta_i >= 0 (mirror the slice: theta_i -> -theta_i, theta_o -> "
                                  "-theta_o)")
    if not np.all(np.isfinite(slices.values)):
        k, c = (int(x) for x in np.argwhere(~np.isfinite(slices.values))[0])
        raise ReconstructionError(f"{src}: sample {k}, channel {slices.channels[c]}: value is "
                                  f"{slices.values[k, c]}; NaN and infinity cannot be revolved")
    f_all, _ = slices.brdf()
    if not np.all(np.isfinite(f_all)):
        k = int(np.argmax(~np.all(np.isfinite(f_all), axis=1)))
        raise ReconstructionError(f"{src}: sample {k}: converting {slices.quantity} to f_r gives a non-finite "
                                  f"value at theta_o = {to_all[k]} deg")
    if blind_spot_deg is not None and not (math.isfinite(blind_spot_deg) and blind_spot_deg >= 0):
        raise ReconstructionError(f"blind_spot_deg must be None or a number of degrees >= 0, "
                                  f"got {blind_spot_deg}")
    notes: list[str] = []
    out: list[_Incidence] = []
    for t in np.unique(ti_all):  # one cleaned curve per measured incidence: a handful
        idx = np.nonzero(ti_all == t)[0]
        to = to_all[idx]
        if sort:
            o = np.argsort(to, kind="stable")
            idx, to = idx[o], to[o]
        d = np.diff(to)
        if np.any(d == 0):
            k = int(np.argmax(d == 0))
            raise ReconstructionError(f"{src}: duplicate samples {idx[k]} and {idx[k + 1]} at theta_i_deg = {t}, "
                                      f"theta_o_deg = {to[k]}")
        if np.any(d < 0):
            k = int(np.argmax(d < 0))
            raise ReconstructionError(
                f"{src}: samples at theta_i_deg = {t} are not sorted by theta_o_deg: sample {idx[k + 1]} "
                f"(theta_o_deg = {to[k + 1]}) comes after sample {idx[k]} ({to[k]}); the thesis's curve is "
                "ordered: pass sort=True or use Slice.sorted()")
        f = f_all[idx]
        neg = f < 0
        n_clipped = int(neg.sum())
        f = np.where(neg, 0.0, f)
        retro_dist = np.abs(to + t)
        if blind_spot_deg is None:
            # the shared rule (negative values were set to 0 above); a curve of zeros only is refused below
            drop = blind_spot_missing(np.full(to.shape, t), to, f, DEFAULT_BLIND_SPOT_DEG) & np.any(f > 0)
        else:
            drop = retro_dist <= blind_spot_deg
        keep = ~drop
        dropped_between = np.cumsum(drop)[keep]  # rows dropped before each kept sample
        to, f = to[keep], f[keep]
        if to.size < 3:
            what = "no sample" if to.size == 0 else f"{to.size} sample(s)"
            raise ReconstructionError(f"{src}: theta_i_deg = {t}: {what} left to revolve (after dropping "
                                      f"{int(drop.sum())} blind-spot row(s)); at least 3 are needed")
        lum = f.sum(axis=1)
        if not np.any(lum > 0):
            raise ReconstructionError(f"{src}: theta_i_deg = {t}: every value is zero (or negative); there is "
                                      "no reflection to revolve")
        gaps = np.diff(to)
        nb = np.maximum(np.r_[gaps[1:], 0.0], np.r_[0.0, gaps[:-1]]) if gaps.size > 1 else gaps
        hole = (np.diff(dropped_between) > 0) | ((gaps > 2.5 * nb) & (gaps.size > 2))
        inc = _Incidence(math.radians(float(t)), np.radians(to), f, lum, hole, int(drop.sum()), n_clipped)
        if inc.n_removed:
            notes.append(f"theta_i {t:g} deg: {inc.n_removed} blind-spot row(s) near the retro direction "
                         "dropped as missing data")
        if n_clipped:
            notes.append(f"theta_i {t:g} deg: {n_clipped} negative value(s) (dark-subtraction noise) set to 0")
        inc.holes_deg = [(round(float(to[i]), 6), round(float(to[i + 1]), 6)) for i in np.nonzero(hole)[0]]
        if bridge:
            added = _bridge_holes(inc)
            if added:
                notes.append(f"theta_i {t:g} deg: {added} sample(s) interpolated across the hole(s) "
                             f"{inc.holes_deg} deg")
        out.append(inc)
    return out, notes


def _classify(inc: _Incidence, a: int, b: int) -> tuple[str, float]:
    """Lobe interpretation of sub-curve [a, b]: (kind, peak theta_o in radians)."""
    seg = inc.lum[a:b + 1]
    k = int(np.argmax(seg))
    peak = float(inc.theta_o[a + k])
    n = inc.lum.size
    at_cut = (k == 0 and a > 0) or (k == seg.size - 1 and b < n - 1)  # the flank of a neighbour's lobe
    flat = seg.max() <= _FLAT_RATIO * seg.min()
    if at_cut or flat:
        return "diffuse", peak
    ti = inc.theta_i
    dist = np.array([abs(peak - ti), abs(peak + ti), abs(peak)])  # forward, back, normal: ties go first
    k = int(np.argmin(dist))
    if dist[k] > _LOBE_REACH:  # e.g. the rise towards grazing at the end of a slice: not a lobe
        return "diffuse", peak
    return ("forward", "back", "diffuse")[k], peak


def _analyse(inc: _Incidence, axis: str, smoothing: float, min_turn_deg: float) -> None:
    """Fill in the sub-curves, their axes and interpretations of one incidence."""
    pts = thesis_points_from_slice(inc.theta_o, inc.lum)
    inc.ranges = _split(inc.theta_o, inc.lum, smoothing, min_turn_deg)  # the angles, also of zero values
    inc.axes, inc.kinds, inc.peaks = [], [], []
    for a, b in inc.ranges:  # a handful of sub-curves
        kind, peak = _classify(inc, a, b)
        # "auto": a diffuse arc turns about the vertical through its top (2.1); a lobe about its principal
        # axis (2.4) unless it is clearly more symmetric about the vertical one
        if axis == "auto" and kind == "diffuse":
            inc.axes.append(subcurve_axis(pts[a:b + 1], "vertical"))
        else:
            inc.axes.append(subcurve_axis(pts[a:b + 1], axis, prefer="pca"))
        inc.kinds.append(kind)
        inc.peaks.append(peak)
    # An arc from a forward lobe to the grazing end of the slice (or from a back lobe to the other end) is
    # that lobe's tail towards grazing, not diffuse reflection: revolved about the normal it would carry
    # the lobe's grazing rise to every incidence.
    inc.tails = []
    if len(inc.kinds) > 1 and inc.kinds[-1] == "diffuse" and inc.kinds[-2] == "forward":
        inc.kinds[-1] = "forward"
        inc.tails.append(len(inc.kinds) - 1)
    if len(inc.kinds) > 1 and inc.kinds[0] == "diffuse" and inc.kinds[1] == "back":
        inc.kinds[0] = "back"
        inc.tails.append(0)


def _loglin(xq: Array, x: Array, y: Array) -> Array:
    """Interpolate y (n, C) >= 0 at xq (x increasing): linear in log y where both neighbours are > 0."""
    n = x.size
    if n == 1:
        return np.repeat(y, xq.size, axis=0)
    i = np.clip(np.searchsorted(x, xq, side="right") - 1, 0, n - 2)
    dx = x[i + 1] - x[i]
    t = np.clip(np.divide(xq - x[i], dx, out=np.zeros_like(xq), where=dx > 0), 0.0, 1.0)[:, None]
    y0, y1 = y[i], y[i + 1]
    lin = y0 + (y1 - y0) * t
    pos = (y0 > 0) & (y1 > 0)
    with np.errstate(divide="ignore", invalid="ignore"):
        lg = np.exp(np.log(np.where(pos, y0, 1.0)) * (1.0 - t) + np.log(np.where(pos, y1, 1.0)) * t)
    return np.where(pos, lg, lin)


def _subcurve_points(inc: _Incidence, a: int, b: int, step: float | None) -> tuple[Array, Array]:
    """Sub-curve [a, b] as (x, z) points (M, 2) and channel values (M, C), resampled every ``step`` radians."""
    to, f = inc.theta_o[a:b + 1], inc.f[a:b + 1]
    if step is not None and to.size > 1:
        m = int(min(max(math.ceil((to[-1] - to[0]) / step) + 1, to.size), 100_000))
        tq = np.union1d(np.linspace(to[0], to[-1], m), to)
        k = np.clip(np.searchsorted(to, tq, side="right") - 1, 0, to.size - 2)
        gap = inc.hole_after[a:b][k] & (tq > to[k]) & (tq < to[k + 1])  # no data there: do not invent any
        tq = tq[~gap]
        f = _loglin(tq, to, f)
        to = tq
    return thesis_points_from_slice(to, f.sum(axis=1)), f


def _hemisphere_of(inc: _Incidence, resolution_deg: float, fill: str, upsample: bool) -> HemisphereMap:
    """The thesis's merged solid for one analysed incidence."""
    step = math.radians(resolution_deg) / 2.0 if upsample else None
    n_steps = int(math.ceil(720.0 / resolution_deg))
    solids, vals = [], []
    for (a, b), ax in zip(inc.ranges, inc.axes, strict=True):  # one solid per sub-curve
        pts, f = _subcurve_points(inc, a, b, step)
        solids.append(revolve(pts, ax, n_steps).reshape(-1, 3))
        vals.append(np.repeat(f, n_steps, axis=0))
    hm = merge_solids(np.concatenate(solids), np.concatenate(vals), resolution_deg=resolution_deg, fill=fill)
    hm.theta_i_deg = math.degrees(inc.theta_i)
    hm.subcurves = _subcurve_report(inc)
    return hm


def _subcurve_report(inc: _Incidence) -> list[dict[str, Any]]:
    out = []
    for (a, b), ax, kind, peak in zip(inc.ranges, inc.axes, inc.kinds, inc.peaks, strict=True):
        out.append({
            "theta_o_range_deg": [round(math.degrees(inc.theta_o[a]), 6), round(math.degrees(inc.theta_o[b]), 6)],
            "samples": int(b - a + 1),
            "axis": ax.kind,
            "axis_angle_deg": round(math.degrees(ax.angle), 4),
            "axis_x_shift": float(ax.x_shift()),
            "asymmetry": round(float(ax.asymmetry), 6) if math.isfinite(ax.asymmetry) else None,
            "peak_theta_o_deg": round(math.degrees(peak), 6),
            "interpretation": kind,
        })
        if len(out) - 1 in inc.tails:
            out[-1]["grazing_tail"] = True  # the lobe's tail towards grazing, joined to its neighbour
    return out


def thesis_hemisphere(slices: Slice, theta_i_deg: float | None = None, *, axis: str = "auto",
                      smoothing: float = DEFAULT_SMOOTHING_DEG, min_turn_deg: float = DEFAULT_MIN_TURN_DEG,
                      resolution_deg: float = 1.0, fill: str = "zero", upsample: bool = True,
                      sort: bool = False, blind_spot_deg: float | None = None) -> HemisphereMap:
    """The thesis's result for one measured incidence: the merged solid of revolution on the hemisphere.

    Splits the slice's curve at ``theta_i_deg`` (default: the only, or the first, incidence) into
    sub-curves, revolves each about its axis and merges the solids (see the module docstring); returns
    directions, intensities and channel values. ``upsample`` resamples each sub-curve (log-linearly) every
    half grid step before revolving, so that sparse samples leave no empty rings between them (not in the
    thesis; without it such rings are uncovered and get ``fill``).
    """
    if axis not in _AXIS_KINDS:
        raise ReconstructionError(f"axis must be one of {', '.join(_AXIS_KINDS)}, got {axis!r}")
    incs, _ = _prepare(slices, sort, blind_spot_deg, bridge=fill == "interpolate")
    if theta_i_deg is None:
        inc = incs[0]
    else:
        have = np.array([math.degrees(i.theta_i) for i in incs])
        k = int(np.argmin(np.abs(have - theta_i_deg)))
        if abs(have[k] - theta_i_deg) > 1e-9:
            raise ReconstructionError(f"theta_i_deg = {theta_i_deg} was not measured; the slice has "
                                      f"{', '.join(f'{h:g}' for h in have)}")
        inc = incs[k]
    _analyse(inc, axis, smoothing, min_turn_deg)
    return _hemisphere_of(inc, resolution_deg, fill, upsample)


# --- the extension: lobes relative to their axes, for every (wi, wo) -------------------------------------


def _side_segments(inc: _Incidence, rng: tuple[int, int], axis_angle: float, side: int
                   ) -> tuple[Array, Array, bool, NDArray[np.bool_]] | None:
    """Samples of sub-curve ``rng`` on one side of the axis as (psi ascending, values, open end, holes).

    ``side`` +1 takes theta_o >= axis, -1 theta_o <= axis. A sub-curve straddling the axis gets a point
    interpolated on it (psi = 0). ``open`` is True when the far end is the end of the measured slice.
    ``holes`` (m - 1,) marks gaps between consecutive returned samples that are missing data.
    """
    a, b = rng
    to, f = inc.theta_o[a:b + 1], inc.f[a:b + 1]
    hole = inc.hole_after[a:b]
    psi = side * (to - axis_angle)
    idx = np.nonzero(psi >= 0)[0]
    if idx.size == 0:
        return None
    ps, fs = psi[idx], f[idx]
    hs = hole[idx[:-1]]  # gap after each kept sample (in theta_o order; the kept samples are contiguous)
    k = int(np.searchsorted(to, axis_angle)) - 1  # the gap holding the axis
    if psi.min() < 0 < psi.max() and not hole[k]:  # straddles the axis: add the point on it (not in a hole)
        f0 = _loglin(np.array([axis_angle]), to, f)
        h0 = np.array([False])
        if side > 0:
            ps, fs, hs = np.r_[0.0, ps], np.concatenate([f0, fs]), np.r_[h0, hs]
        else:
            ps, fs, hs = np.r_[ps, 0.0], np.concatenate([fs, f0]), np.r_[hs, h0]
    if side < 0:
        ps, fs, hs = ps[::-1], fs[::-1], hs[::-1]
    far = b if side > 0 else a
    is_open = far == (inc.theta_o.size - 1 if side > 0 else 0)
    return ps, fs, bool(is_open), hs
