"""The thesis's building blocks (Tramontina, TU Delft 2023, sections 2.1-2.4), on the slice's ordered 2D polar
curve (points ``value * (sin theta_o, cos theta_o)`` as (x, z), x towards the specular side): sub-curves,
their axes, the revolution and the O(n log n) merge. See :mod:`reconstruction.methods.revolve`.

Units: degrees where a name says ``_deg``; radians and unit vectors inside.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.ndimage import gaussian_filter1d
from scipy.spatial import cKDTree

from reconstruction.base import ReconstructionError
from reconstruction.core.geometry import rodrigues

Array = NDArray[np.float64]

DEFAULT_SMOOTHING_DEG = 5.0
"""Default ``smoothing``: Gaussian sigma, degrees of theta_o, applied to log(value) before the acceleration."""
DEFAULT_MIN_TURN_DEG = 20.0
"""Default ``min_turn_deg``: a positive-acceleration run must turn the tangent by this much to split there."""

_AXIS_KINDS = ("vertical", "pca", "auto")
_FILLS = ("interpolate", "zero")
_LOBE_AXES = ("measured", "semantic")
_KINDS = ("diffuse", "forward", "back")
_FLAT_RATIO = 2.0  # a sub-curve whose max/min luminance is below this is diffuse (no lobe)
_MAX_OFFSET = math.radians(15.0)  # largest axis offset kept from a measured (vertical/PCA) axis
_LOBE_REACH = math.radians(30.0)  # a lobe's peak lies at most this far from its semantic direction
_LOG_FLOOR = 1e-300
_COV_MIN = 1e-6  # a profile side counts as covered at a point where its interpolated coverage exceeds this
_FILL_WEIGHT = 1e-3  # coverage weight of a diffuse side filled in from the other side
_LOBE_MIN_COV = 0.02  # a forward or back lobe claims a direction where its blended coverage exceeds this
_EVAL_CHUNK = 32768  # eval works in blocks of this many pairs: 40 % faster than 200k (cache)


def _check_curve(points: ArrayLike, what: str = "curve") -> tuple[Array, Array, Array]:
    """Validate an ordered polar curve (N, 2) -> (points, signed theta_o radians, intensity)."""
    p = np.asarray(points, dtype=np.float64)
    if p.ndim != 2 or p.shape[1] != 2:
        raise ReconstructionError(f"{what}: expected points of shape (N, 2) as (x, z), got {p.shape}")
    if p.shape[0] == 0:
        raise ReconstructionError(f"{what}: empty curve, nothing to revolve")
    if not np.all(np.isfinite(p)):
        k = int(np.argmax(~np.all(np.isfinite(p), axis=1)))
        raise ReconstructionError(f"{what}: point {k} is not finite ({p[k].tolist()})")
    if np.any(p[:, 1] < 0):
        k = int(np.argmax(p[:, 1] < 0))
        raise ReconstructionError(f"{what}: point {k} lies below the surface (z = {p[k, 1]})")
    r = np.hypot(p[:, 0], p[:, 1])
    return p, np.arctan2(p[:, 0], p[:, 1]), r


def _runs(mask: NDArray[np.bool_]) -> tuple[NDArray[np.intp], NDArray[np.intp]]:
    """Start and stop (exclusive) indices of the runs of True in a 1D mask."""
    m = np.concatenate([[False], mask, [False]]).astype(np.int8)
    d = np.diff(m)
    return np.nonzero(d == 1)[0], np.nonzero(d == -1)[0]


# --- 2.3: sub-curves -------------------------------------------------------------------------------------


def _turning(theta: Array, lum: Array, smoothing_deg: float) -> tuple[Array, Array]:
    """Tangent turning of the polar curve on a uniform theta grid: (grid theta (M,), turning per step (M-1,)).

    The curve r(theta) is resampled (linear in log r) on a uniform grid, log r is smoothed with a Gaussian of
    sigma ``smoothing_deg`` and the tangent direction follows from u' = d log r / d theta alone:
    p' ~ u' e_r + e_theta. Positive turning is counter-clockwise in the (x, z) plane: the curve bends
    towards the origin, the thesis's positive acceleration. Scale free, so a dynamic range of 1e8 is harmless.
    """
    span = theta[-1] - theta[0]
    steps = np.diff(theta)
    h = float(np.clip(np.median(steps) / 2.0, math.radians(0.02), math.radians(0.5)))
    m = int(min(max(math.ceil(span / h) + 1, 3), 20001))
    grid = np.linspace(theta[0], theta[-1], m)
    h = grid[1] - grid[0]
    top = float(lum.max())
    u = np.log(np.maximum(lum, top * 1e-12))
    ug = np.interp(grid, theta, u)
    if smoothing_deg > 0:
        ug = gaussian_filter1d(ug, math.radians(smoothing_deg) / h, mode="nearest")
    du = np.gradient(ug, h)
    s, c = np.sin(grid), np.cos(grid)
    tang = np.unwrap(np.arctan2(du * c - s, du * s + c))  # angle of (x', z') measured from +x
    return grid, np.diff(tang)


def split_subcurves(points: ArrayLike, *, smoothing: float = DEFAULT_SMOOTHING_DEG,
                    min_turn_deg: float = DEFAULT_MIN_TURN_DEG) -> list[tuple[int, int]]:
    """Split an ordered polar curve (N, 2) of (x, z) points into sub-curves (thesis 2.3).

    The acceleration along the curve is the turning of its tangent: negative where the curve bends away
    from the origin (around a lobe), positive where it bends towards it (the valley between two lobes). A
    cut falls at the median point of every positive run that lies between negative runs. ``smoothing`` is
    the sigma, in degrees of theta_o, of a Gaussian applied to log(value) along the curve first (0 = the raw
    curve); positive runs that turn the tangent by less than ``min_turn_deg`` in total, and negative blips
    smaller than that inside a valley, are noise. Returns inclusive index ranges (start, stop) covering
    the curve in order; neighbours share their cut point. Points must be ordered by strictly increasing
    theta_o (from the -x side to the +x side).
    """
    _, theta, r = _check_curve(points)
    n = theta.size
    if n < 3:
        raise ReconstructionError(f"curve: {n} point(s); at least 3 are needed to follow its acceleration")
    if not np.any(r > 0):
        raise ReconstructionError("curve: every value is zero; there is no curve to split")
    if not np.all(r > 0):  # a zero value sits at the origin and has no direction: take its neighbours'
        idx = np.arange(n, dtype=np.float64)
        known = r > 0
        ki, kt = idx[known], theta[known]
        step = float(np.median(np.diff(kt) / np.diff(ki))) if ki.size > 1 else math.pi / (2 * n)
        step = step if step > 0 else math.pi / (2 * n)
        theta = np.interp(idx, ki, kt)  # between known neighbours; beyond them, go on in the same steps
        theta = np.where(idx < ki[0], kt[0] - (ki[0] - idx) * step, theta)
        theta = np.where(idx > ki[-1], kt[-1] + (idx - ki[-1]) * step, theta)
    return _split(theta, r, smoothing, min_turn_deg)


def _split(theta: Array, r: Array, smoothing: float, min_turn_deg: float) -> list[tuple[int, int]]:
    """:func:`split_subcurves` on angles (radians, increasing) and values (>= 0, some > 0) directly."""
    if np.any(np.diff(theta) <= 0):
        k = int(np.argmax(np.diff(theta) <= 0))
        raise ReconstructionError(f"curve: points {k} and {k + 1} are not in order of increasing theta_o "
                                  f"({math.degrees(theta[k]):.6g} then {math.degrees(theta[k + 1]):.6g} deg)")
    if smoothing < 0 or not math.isfinite(smoothing):
        raise ReconstructionError(f"smoothing must be a finite number of degrees >= 0, got {smoothing}")
    grid, turn = _turning(theta, r, smoothing)
    return _cuts_to_ranges(theta, grid, turn, math.radians(min_turn_deg))


def _mark_runs(size: int, starts: NDArray[np.intp], stops: NDArray[np.intp]) -> NDArray[np.bool_]:
    """Boolean mask of length ``size`` that is True inside the given [start, stop) runs."""
    d = np.zeros(size + 1, dtype=np.int64)
    np.add.at(d, starts, 1)
    np.add.at(d, stops, -1)
    return np.cumsum(d[:-1]) > 0


def _cuts_to_ranges(theta: Array, grid: Array, turn: Array, thr: float) -> list[tuple[int, int]]:
    """Sub-curve index ranges from the turning on the grid (see :func:`split_subcurves`)."""
    n = theta.size
    csum = np.concatenate([[0.0], np.cumsum(turn)])
    pos = turn > 0
    # Negative blips inside a valley (between two positive runs, turning less than the threshold) are noise.
    starts, stops = _runs(~pos)
    blip = (starts > 0) & (stops < turn.size) & (csum[starts] - csum[stops] < thr)
    pos |= _mark_runs(turn.size, starts[blip], stops[blip])
    starts, stops = _runs(pos)
    keep = (starts > 0) & (stops < turn.size) & (csum[stops] - csum[starts] >= thr)
    cut_theta = []
    for a, b in zip(starts[keep], stops[keep], strict=True):  # one per valley: a handful
        idx = a + np.nonzero(turn[a:b] > 0)[0]
        mid = int(idx[(idx.size - 1) // 2])  # the median point of the positive run
        cut_theta.append(0.5 * (grid[mid] + grid[mid + 1]))
    ct = np.asarray(cut_theta, dtype=np.float64)
    hi = np.clip(np.searchsorted(theta, ct), 1, n - 1)
    lo = hi - 1
    near = np.where(np.abs(theta[hi] - ct) < np.abs(theta[lo] - ct), hi, lo)
    cuts = np.unique(near[(near > 0) & (near < n - 1)])
    bounds = np.concatenate([[0], cuts, [n - 1]]).astype(int)
    return [(int(a), int(b)) for a, b in zip(bounds[:-1], bounds[1:], strict=True)]


# --- 2.1 / 2.4: axes -------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Axis:
    """An axis of revolution in the (x, z) plane of incidence: a line through ``point`` along ``direction``.

    ``kind`` is "vertical" (through the highest point) or "pca" (first principal component); ``direction``
    is a unit (x, z) vector with z >= 0; ``asymmetry`` is how badly the sub-curve mirrors onto itself across
    the axis (mean distance / sub-curve size; 0 = symmetric); ``overshoot`` is the largest intensity of the
    solid over the sub-curve's own (revolving about an axis off the origin can exceed it). "auto" compares
    ``score`` = asymmetry + (overshoot - 1 when above 1).
    """

    kind: str
    point: Array
    direction: Array
    asymmetry: float = float("nan")
    overshoot: float = float("nan")

    @property
    def score(self) -> float:
        """What "auto" minimises: asymmetry + (overshoot - 1 where above 1); dimensionless, inf if untestable."""
        return self.asymmetry + max(0.0, self.overshoot - 1.0)

    @property
    def angle(self) -> float:
        """Signed angle (radians, theta_o convention) of the direction this axis stands for, from the origin.

        For a vertical axis the direction of its highest point; for a principal axis its own direction.
        """
        if self.kind == "vertical":
            return float(math.atan2(self.point[0], self.point[1]))
        return float(math.atan2(self.direction[0], self.direction[1]))

    def x_shift(self) -> float:
        """x where the axis crosses z = 0: the shift along x that makes it pass through the origin (2.4).

        For an axis parallel to the surface there is none; its own ``point`` x is returned and
        :func:`revolve` shifts by the whole point instead (the rotation about the line is the same).
        """
        kx, kz = self.direction
        if abs(kz) < 1e-9:
            return float(self.point[0])
        return float(self.point[0] - self.point[1] * kx / kz)


def _vertical_axis(p: Array) -> Axis:
    z = p[:, 1]
    top = np.isclose(z, z.max(), rtol=1e-9, atol=0.0)  # the mean of equally high points
    return Axis("vertical", np.array([float(p[top, 0].mean()), float(z.max())]), np.array([0.0, 1.0]))


def _pca_axis(p: Array) -> Axis:
    c = p.mean(axis=0)
    if p.shape[0] < 2 or np.allclose(p, c):
        return Axis("pca", c, np.array([0.0, 1.0]))
    _, _, vt = np.linalg.svd(p - c, full_matrices=False)
    k = vt[0] / np.linalg.norm(vt[0])
    if k[1] < 0 or (k[1] == 0 and k[0] < 0):
        k = -k
    return Axis("pca", c, k)


def _asymmetry(p: Array, ax: Axis, max_points: int = 256) -> float:
    """How badly a sub-curve mirrors onto itself across ``ax``: mean distance / size, inf if untestable.

    Only the points with a counterpart across the axis count (those whose distance from the axis does not
    exceed the farthest point on the other side), so a diffuse arc cut short on one side by a lobe is judged
    on the part around its axis. Fewer than 3 such points: inf.
    """
    if p.shape[0] < 3:
        return float("inf")
    k = ax.direction
    nrm = np.array([k[1], -k[0]])
    off = (p - ax.point) @ nrm  # signed distance from the axis
    reach = min(float(off.max()), float(-off.min()))
    step = max(1, p.shape[0] // max_points)
    q = p[::step][np.abs(off[::step]) <= reach + 1e-12 * max(1.0, reach)]
    if q.shape[0] < 3:
        return float("inf")
    rel = q - ax.point
    refl = ax.point + 2.0 * (rel @ k)[:, None] * k[None, :] - rel
    a = p[:-1:step]
    b = p[np.minimum(np.arange(0, p.shape[0] - 1, step) + step, p.shape[0] - 1)]
    ab = b - a
    ll = np.maximum(np.sum(ab * ab, axis=1), 1e-300)
    t = np.clip(np.einsum("mij,ij->mi", refl[:, None, :] - a[None], ab) / ll, 0.0, 1.0)
    d = np.linalg.norm(refl[:, None, :] - (a[None] + t[..., None] * ab[None]), axis=-1).min(axis=1)
    size = float(np.max(np.hypot(p[:, 0], p[:, 1])))
    return float(d.mean() / size) if size > 0 else 0.0


def _overshoot(p: Array, ax: Axis) -> float:
    """Largest intensity of the solid of revolution over the sub-curve's largest: the farthest point of each
    ring from the origin lies in the plane of incidence, so it is the point itself or its mirror image."""
    rel = p - ax.point
    refl = ax.point + 2.0 * (rel @ ax.direction)[:, None] * ax.direction[None, :] - rel
    top = float(np.max(np.hypot(p[:, 0], p[:, 1])))
    return float(max(top, float(np.max(np.hypot(refl[:, 0], refl[:, 1])))) / top) if top > 0 else 1.0


def subcurve_axis(points: ArrayLike, kind: str = "auto", prefer: str = "vertical") -> Axis:
    """Axis of revolution of one sub-curve (M, 2) of (x, z) points (thesis 2.1, 2.4).

    "vertical": the vertical line through the highest point (through the mean x of equally high points);
    "pca": the line through the points' mean along their first principal component; "auto": the one the
    sub-curve is more symmetric about, without inflating it (:attr:`Axis.score`): ``prefer`` unless the
    other one is clearly better (below 0.8 times its score).
    """
    if kind not in _AXIS_KINDS:
        raise ReconstructionError(f"axis must be one of {', '.join(_AXIS_KINDS)}, got {kind!r}")
    if prefer not in ("vertical", "pca"):
        raise ReconstructionError(f"prefer must be 'vertical' or 'pca', got {prefer!r}")
    p, _, _ = _check_curve(points, "sub-curve")
    cands = {}
    for k, make in (("vertical", _vertical_axis), ("pca", _pca_axis)):
        if kind in (k, "auto"):
            v = make(p)
            cands[k] = Axis(v.kind, v.point, v.direction, _asymmetry(p, v), _overshoot(p, v))
    if kind != "auto":
        return cands[kind]
    other = "pca" if prefer == "vertical" else "vertical"
    if cands[other].score < 0.8 * cands[prefer].score:  # inf < x is False
        return cands[other]
    return cands[prefer]


# --- 2.1 / 2.4: revolution -------------------------------------------------------------------------------


def revolve(points: ArrayLike, axis: Axis, n_steps: int = 720) -> Array:
    """Solid of revolution of a sub-curve (M, 2) about ``axis``: points (M, n_steps, 3) in 3D (x, y, z).

    Each curve point becomes a ring of ``n_steps`` points, rotated by 2 pi j / n_steps (j = 0 is the point
    itself) with Rodrigues' formula after shifting along x so that the axis passes through the origin, then
    shifted back (thesis 2.4). Ring j of point m is ``out[m, j]``, so its values are those of point m.
    """
    p, _, _ = _check_curve(points, "sub-curve")
    if n_steps < 1:
        raise ReconstructionError(f"n_steps must be >= 1, got {n_steps}")
    k = np.array([axis.direction[0], 0.0, axis.direction[1]])
    if abs(axis.direction[1]) < 1e-9:  # parallel to the surface: shift by the whole point (same rotation)
        shift = np.array([axis.point[0], 0.0, axis.point[1]])
    else:
        shift = np.array([axis.x_shift(), 0.0, 0.0])
    v = np.stack([p[:, 0], np.zeros(p.shape[0]), p[:, 1]], axis=-1) - shift
    ang = 2.0 * np.pi * np.arange(n_steps) / n_steps
    return rodrigues(v[:, None, :], k, ang[None, :]) + shift


# --- 2.2: snapping, sorting, merging ---------------------------------------------------------------------


@dataclass(frozen=True)
class _Grid:
    resolution: float  # radians
    theta: Array  # ring polar angles (J + 1,)
    counts: NDArray[np.int64]  # cells per ring
    offsets: NDArray[np.int64]  # first key of each ring


_GRIDS: dict[float, _Grid] = {}


def _grid(resolution_deg: float) -> _Grid:
    if not (math.isfinite(resolution_deg) and 0.05 <= resolution_deg <= 30.0):
        raise ReconstructionError(f"resolution_deg must lie in [0.05, 30], got {resolution_deg}")
    g = _GRIDS.get(resolution_deg)
    if g is None:
        d = math.radians(resolution_deg)
        j = int(round(90.0 / resolution_deg))
        theta = np.arange(j + 1) * (np.pi / 2 / j)
        counts = np.maximum(1, np.round(2 * np.pi * np.sin(theta) / d)).astype(np.int64)
        counts[0] = 1
        offsets = np.concatenate([[0], np.cumsum(counts)[:-1]])
        g = _Grid(d, theta, counts, offsets)
        _GRIDS[resolution_deg] = g
    return g


def direction_grid(resolution_deg: float = 1.0) -> Array:
    """The evenly distributed directions of the upper hemisphere the merge snaps to: unit vectors (K, 3).

    Rings of equal polar-angle spacing ``resolution_deg`` from the normal to the horizon, each divided into
    equal azimuth steps of about the same arc length (one cell at the pole); key k is row k.
    """
    g = _grid(resolution_deg)
    ring = np.repeat(np.arange(g.theta.size), g.counts)
    k = np.arange(int(g.counts.sum())) - g.offsets[ring]
    phi = 2.0 * np.pi * k / g.counts[ring]
    t = g.theta[ring]
    return np.stack([np.sin(t) * np.cos(phi), np.sin(t) * np.sin(phi), np.cos(t)], axis=-1)


def snap_directions(v: ArrayLike, resolution_deg: float = 1.0) -> NDArray[np.int64]:
    """Key (row of :func:`direction_grid`) of the grid direction nearest in angle to each vector (..., 3).

    -1 for zero vectors and for directions more than half a step below the horizon. O(1) per vector.
    """
    g = _grid(resolution_deg)
    v = np.asarray(v, dtype=np.float64)
    rho = np.hypot(v[..., 0], v[..., 1])
    theta = np.arctan2(rho, v[..., 2])
    phi = np.mod(np.arctan2(v[..., 1], v[..., 0]), 2.0 * np.pi)
    j = np.rint(theta / (g.theta[1] - g.theta[0])).astype(np.int64)
    ok = (j < g.theta.size) & ((rho > 0) | (v[..., 2] > 0))
    j = np.clip(j, 0, g.theta.size - 1)
    n = g.counts[j]
    k = np.mod(np.rint(phi * n / (2.0 * np.pi)).astype(np.int64), n)
    return np.where(ok, g.offsets[j] + k, -1)


@dataclass
class HemisphereMap:
    """The merged solid for one incidence on the evenly distributed directions (thesis section 3 results).

    ``directions`` (K, 3) unit vectors; ``intensity`` (K,) the merged solid's radius there (luminance-like
    channel sum; 0 where uncovered and filled with zeros); ``values`` (K, C) the channel values of the point
    that won each direction; ``covered`` (K,) which directions some solid reached before any fill.
    """

    directions: Array
    intensity: Array
    values: Array
    covered: NDArray[np.bool_]
    resolution_deg: float
    fill: str
    theta_i_deg: float = float("nan")
    subcurves: list[dict[str, Any]] = field(default_factory=list)

    @property
    def coverage(self) -> float:
        """Fraction of the grid's directions some solid reached (before any fill)."""
        return float(self.covered.mean()) if self.covered.size else 0.0


def merge_solids(points: ArrayLike, values: ArrayLike | None = None, *, resolution_deg: float = 1.0,
                 fill: str = "zero") -> HemisphereMap:
    """Merge solids given as 3D points (..., 3) into one hemisphere map, in O(n log n) (thesis 2.2).

    Every point's direction is snapped to :func:`direction_grid` (``resolution_deg`` apart), the points are
    sorted by (direction key, decreasing intensity) and the first of each key wins: the highest intensity
    per direction. ``values`` (..., C) are carried along (default: the intensity itself). Directions no point
    reached get 0 (``fill="zero"``, the thesis) or the inverse-distance average of the nearest reached
    directions (``fill="interpolate"``).
    """
    if fill not in _FILLS:
        raise ReconstructionError(f"fill must be one of {', '.join(_FILLS)}, got {fill!r}")
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    inten = np.linalg.norm(p, axis=1)
    vals = inten[:, None] if values is None else np.asarray(values, dtype=np.float64).reshape(p.shape[0], -1)
    ok = np.isfinite(inten) & np.all(np.isfinite(vals), axis=1)
    keys = snap_directions(p, resolution_deg)
    ok &= keys >= 0
    keys, inten, vals = keys[ok], inten[ok], vals[ok]
    order = np.lexsort((-inten, keys))  # O(n log n): by key, then by decreasing intensity
    sk = keys[order]
    first = np.ones(sk.size, dtype=bool)
    first[1:] = sk[1:] != sk[:-1]
    win = order[first]
    dirs = direction_grid(resolution_deg)
    k_total = dirs.shape[0]
    out_i = np.zeros(k_total)
    out_v = np.zeros((k_total, vals.shape[1]))
    covered = np.zeros(k_total, dtype=bool)
    out_i[keys[win]] = inten[win]
    out_v[keys[win]] = vals[win]
    covered[keys[win]] = True
    if fill == "interpolate" and covered.any() and not covered.all():
        tree = cKDTree(dirs[covered])
        kn = int(min(6, covered.sum()))
        d, idx = tree.query(dirs[~covered], k=kn)
        d = d.reshape(-1, kn)
        idx = idx.reshape(-1, kn)
        w = 1.0 / np.maximum(d, 1e-9) ** 2
        w /= w.sum(axis=1, keepdims=True)
        out_i[~covered] = np.einsum("nk,nk->n", w, out_i[covered][idx])
        out_v[~covered] = np.einsum("nk,nkc->nc", w, out_v[covered][idx])
    return HemisphereMap(dirs, out_i, out_v, covered, float(resolution_deg), fill)


