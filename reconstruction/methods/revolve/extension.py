"""The full-BRDF extension of revolve: every sub-curve of every measured incidence re-expressed as a lobe about
what its axis means (the normal, the mirror direction of wi, wi itself), evaluable at every (wi, wo), and the
models of several incidences blended in theta_i (see docs/revolve.md and :mod:`reconstruction.methods.revolve`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.base import ReconstructionError
from reconstruction.core.slicedata import Slice

from . import grazing, incidence
from .aperture import hold_peaks_over_cone
from .incidence import _analyse, _hemisphere_of, _Incidence, _lend_peaks, _loglin, _prepare, _subcurve_report
from .thesis import (
    _AXIS_KINDS,
    _COV_MIN,
    _EVAL_CHUNK,
    _FILL_WEIGHT,
    _FILLS,
    _KINDS,
    _LOBE_AXES,
    _LOBE_MIN_COV,
    _MAX_OFFSET,
    DEFAULT_MIN_TURN_DEG,
    DEFAULT_SMOOTHING_DEG,
    Array,
    HemisphereMap,
)


@dataclass
class _Component:
    """One lobe of one incidence: a two-sided profile against the angle psi from its axis.

    The axis is the lobe's semantic direction (normal / mirror of wi / wi) turned by ``offset`` radians in
    the plane of incidence (towards +theta_o). Profiles live on a grid uniform in the chord
    u = |wo - axis| = 2 sin(psi / 2) (fine near the axis, no arctan needed to look up). ``table``
    (G - 1, 4, C + 1) holds for grid cell i its nodes (i, side +), (i, side -), (i + 1, side +),
    (i + 1, side -): the side's value times its coverage and (last column) the coverage; side + is
    +theta_o from the axis. ``near`` (G, 2 sides, C + 1) holds the nearest covered value and (last column)
    the angular distance to it, for filling directions no lobe covers.
    """

    kind: str
    offset: float
    subcurves: list[int]
    table: Array
    near: Array
    val: Array  # (2, G, C) the profiles (f_r / scale, or the weighted excess), 0 where uncovered
    cov: Array  # (2, G) coverage weight: 1 data, _FILL_WEIGHT filled in from the other side, 0 none
    axis_angle: float = 0.0  # in-plane angle of the axis at the measured incidence (radians)
    excess: bool = False  # the table holds (f - diffuse) cos(theta_i) cos(theta_o): see _eval_model
    cmin: float = 1.0  # smallest cos(theta_i) cos(theta_o) the excess was measured at


@dataclass
class _Model:
    """Lobes of one measured incidence on a chord grid u in [0, 2] of step ``du``."""

    theta_i: float
    du: float
    comps: list[_Component]
    forward_frame: str = "half"
    scale: float = 1.0  # tables hold f_r / scale (scale = the slice's largest value), safe in float32
    floor: Array | None = None  # (C,) / scale: the base of a forward excess when there is no diffuse lobe


def _inplane(comp: _Component, psi_grid: Array, theta_o: Array) -> Array:
    """The diffuse base under a lobe, as :func:`_eval_model` adds it back: ``comp``'s profile (f_r / scale)
    at in-plane angles ``theta_o`` of its own incidence, (m, C). Its own side where covered, else the other
    side, else the nearest covered value (so the base has no step where the diffuse data stop)."""
    d = theta_o - comp.axis_angle
    psi = np.abs(d)
    side = np.where(d >= 0, 0, 1)
    u = 2.0 * np.sin(psi / 2.0)
    du = 2.0 / (psi_grid.size - 1)
    k = np.clip((u / du).astype(np.intp), 0, psi_grid.size - 2)
    t = np.clip(u / du - k, 0.0, 1.0)
    out = np.zeros((theta_o.size, comp.val.shape[-1]))
    done = np.zeros(theta_o.size, dtype=bool)
    for s in (side, 1 - side):  # its own side, else the other one
        c0, c1 = comp.cov[s, k] * (1.0 - t), comp.cov[s, k + 1] * t
        w = c0 + c1
        have = (w > _COV_MIN) & ~done
        v = (comp.val[s, k] * c0[:, None] + comp.val[s, k + 1] * c1[:, None]) / np.maximum(w, 1e-300)[:, None]
        out[have] = v[have]
        done |= have
    if not done.all():
        j = np.rint(u / du).astype(np.intp)
        nr = comp.near[j]  # (m, 2, C + 1)
        pick = np.where(nr[:, 0, -1] <= nr[:, 1, -1], 0, 1)
        out[~done] = nr[np.arange(j.size), pick, :-1][~done]
    return out


def _build_component(inc: _Incidence, kind: str, members: list[int], offset: float, psi_grid: Array,
                     fill: str, scale: float, base: _Component | None = None, excess: bool = False,
                     floor: Array | None = None) -> _Component:
    """Two-sided profile tables of one lobe from its sub-curves (see :class:`_Component`), f_r / scale.

    With ``excess`` the lobe keeps only what rises above ``base`` (the diffuse lobe; without one, the
    constant ``floor`` (C,)), weighted by cos(theta_i) cos(theta_o) of the measurement: the part of a
    microfacet lobe that hardly changes with the incidence (F D G G / 4).
    """
    g, c = psi_grid.size, inc.f.shape[1]
    axis_angle = {"diffuse": 0.0, "forward": inc.theta_i, "back": -inc.theta_i}[kind] + offset
    val = np.zeros((2, g, c))
    cov = np.zeros((2, g), dtype=bool)
    open_end = [np.inf, np.inf]
    cmin = 1.0
    for s, side in enumerate((1, -1)):
        for j in members:  # the lobe's sub-curves: a handful
            seg = incidence._side_segments(inc, inc.ranges[j], axis_angle, side)
            if seg is None:
                continue
            ps, fs, is_open, hs = seg
            where = np.nonzero((psi_grid >= ps[0]) & (psi_grid <= ps[-1]))[0]
            if where.size == 0:
                continue
            q = psi_grid[where]
            v = _loglin(q, ps, fs)
            if excess:
                to_q = axis_angle + side * q  # in-plane theta_o of these grid points
                if base is not None:
                    v = np.maximum(v - _inplane(base, psi_grid, to_q) * scale, 0.0)
                elif floor is not None:
                    v = np.maximum(v - floor, 0.0)
                w = math.cos(inc.theta_i) * np.cos(to_q)
                cmin = min(cmin, float(w.min()))
                v = v * w[:, None]
            if fill == "zero" and hs.any():  # missing samples stay uncovered (thesis: no data -> 0)
                k = np.clip(np.searchsorted(ps, q, side="right") - 1, 0, hs.size - 1)
                ok = ~(hs[k] & (q > ps[k]) & (q < ps[k + 1]))
                where, v = where[ok], v[ok]
            val[s, where] = np.maximum(val[s, where], v)
            cov[s, where] = True
            if is_open:
                open_end[s] = min(open_end[s], float(ps[-1]))
    if fill == "interpolate":
        # A sample stands for half a step around it: an open end covers one more step at its last value.
        margin = float(np.median(np.diff(inc.theta_o)))
        for s in (0, 1):
            if math.isfinite(open_end[s]) and cov[s].any():
                last = int(np.nonzero(cov[s])[0].max())
                ext = np.nonzero((psi_grid > psi_grid[last]) & (psi_grid <= open_end[s] + margin))[0]
                val[s, ext] = val[s, last]
                cov[s, ext] = True
        # A side cut short by the end of the measurement continues in the shape of the other side.
        base_cov = cov.copy()
        for s in (0, 1):
            o = 1 - s
            if not math.isfinite(open_end[s]):
                continue
            ie = int(np.clip(np.searchsorted(psi_grid, open_end[s], side="right") - 1, 0, g - 1))
            reg = (psi_grid > psi_grid[ie]) & ~base_cov[s] & base_cov[o]
            if not reg.any():
                continue
            ref_s, ref_o = val[s, ie], val[o, ie]
            ratio_ok = base_cov[o, ie] & (ref_o > 1e-9 * scale)  # a ratio to noise is no shape
            ratio = np.divide(ref_s, ref_o, out=np.zeros_like(ref_s), where=ratio_ok)
            top = val[s][base_cov[s]].max(axis=0)  # the continuation makes no new maximum
            val[s, reg] = np.minimum(np.where(ratio_ok, val[o, reg] * ratio, ref_s), top)
            cov[s, reg] = True
        if kind == "diffuse":  # beyond the measured range on both sides: the last value goes on
            for s in (0, 1):
                if math.isfinite(open_end[s]) and cov[s].any():
                    last = int(np.nonzero(cov[s])[0].max())
                    val[s, last + 1:] = val[s, last]
                    cov[s, last + 1:] = True
    covf = cov.astype(np.float64)
    if kind == "diffuse":
        # A revolution about the normal: where one side has no data the other side stands in (so that at
        # eval time every lobe is one blend of two sides, and the base under a lobe has no gap), with a
        # small weight, so that interpolation next to a side's own data keeps to that data.
        for s in (0, 1):
            take = ~cov[s] & cov[1 - s]
            val[s, take] = val[1 - s, take]
            covf[s, take] = _FILL_WEIGHT
        cov |= cov[::-1]
    val /= scale
    gc = np.concatenate([val * covf[..., None], covf[..., None]], axis=-1).transpose(1, 0, 2)  # (G, 2, C+1)
    table = np.concatenate([gc[:-1], gc[1:]], axis=1)  # (G - 1, 4, C + 1)
    near = np.empty((g, 2, c + 1))
    idx = np.arange(g)
    for s in (0, 1):
        if not cov[s].any():
            near[:, s, :c] = 0.0
            near[:, s, c] = 10.0  # radians: farther than anything real
            continue
        left = np.maximum.accumulate(np.where(cov[s], idx, -1))
        right = np.minimum.accumulate(np.where(cov[s], idx, g)[::-1])[::-1]
        dl = np.where(left >= 0, idx - left, g)
        dr = np.where(right < g, right - idx, g)
        nearest = np.where(dl <= dr, left, right)
        near[:, s, :c] = val[s, nearest]
        near[:, s, c] = np.abs(psi_grid - psi_grid[nearest])
    return _Component(kind, offset, members, np.ascontiguousarray(table, dtype=np.float32), near, val, covf,
                      axis_angle, excess, max(cmin, 1e-3))


def _build_model(inc: _Incidence, fill: str, lobe_axis: str, forward_frame: str, excess: bool) -> _Model:
    """The lobes of one analysed incidence: sub-curves grouped by interpretation."""
    gaps = np.diff(inc.theta_o)
    du = float(np.clip(gaps.min() / 8.0, math.radians(0.002), math.radians(0.05)))
    g = int(math.ceil(2.0 / du)) + 1
    u = np.linspace(0.0, 2.0, g)
    psi_grid = 2.0 * np.arcsin(np.clip(u / 2.0, 0.0, 1.0))
    scale = float(inc.f.max())
    # Without a diffuse lobe, a forward lobe's excess stands on the slice's lowest sample: its floor.
    floor = None if "diffuse" in inc.kinds else inc.f[int(np.argmin(inc.lum))]
    comps = []
    for kind in _KINDS:
        members = [j for j, k in enumerate(inc.kinds) if k == kind]
        if not members:
            continue
        offset = 0.0
        if kind != "diffuse" and lobe_axis == "measured":
            top = max(members, key=lambda j: inc.lum[inc.ranges[j][0]:inc.ranges[j][1] + 1].max())
            semantic = inc.theta_i if kind == "forward" else -inc.theta_i
            offset = float(np.clip(inc.axes[top].angle - semantic, -_MAX_OFFSET, _MAX_OFFSET))
        base = comps[0] if comps and comps[0].kind == "diffuse" else None
        comps.append(_build_component(inc, kind, members, offset, psi_grid, fill, scale, base,
                                      excess and kind == "forward", floor))
    return _Model(inc.theta_i, float(u[1] - u[0]), comps, forward_frame, scale,
                  None if floor is None else floor / scale)


def _eval_model(model: _Model, ox: Array, oy: Array, oz: Array, si: Array, ci: Array, fill: str,
                fwd: tuple[Array, Array] | None = None) -> Array:
    """f_r (n, C) of one incidence's lobes for outgoing directions in the canonical frame (wi in the x-z
    plane on the -x side, sin/cos of its theta_i ``si``, ``ci``): the lobe of highest luminance wins. ``fwd``:
    (factor on the divisor's hold, gain) (n,) of a forward excess beyond the last measured incidence (:mod:`.grazing`).

    Each lobe's two side profiles are interpolated at the direction's angle from its axis and blended by
    its azimuth around the axis; a forward or back lobe fades out towards a side where it has no data (that
    side belongs to another lobe; the diffuse lobe has both sides wherever it has either). Geometry is
    float64; profile tables, weights and blends float32 (7 significant digits, any dynamic range).
    """
    n = ox.size
    c = model.comps[0].table.shape[-1] - 1
    inv = 1.0 / model.du
    ncomp = len(model.comps)
    geo = []
    oy2 = oy * oy
    w = np.empty((n, 4), dtype=np.float32)
    best = top = None
    base = None if model.floor is None else np.broadcast_to(model.floor.astype(np.float32), (n, c))
    for comp in model.comps:  # a handful of lobes, each vectorised over all directions
        if comp.kind == "forward" and model.forward_frame == "half":
            # psi = 2 theta_h, theta_h the half vector's angle from the normal turned by offset / 2: the
            # same as the angle from the mirror direction in the plane of incidence, and the microfacet
            # lobe's own variable elsewhere. Chord 2 sin(psi / 2) = 2 |h x n'| / |h|.
            sd, cd = math.sin(comp.offset / 2), math.cos(comp.offset / 2)
            hx, hz = ox - si, oz + ci
            inv_h = 1.0 / np.sqrt(hx * hx + oy2 + hz * hz)
            t = hx * cd - hz * sd  # component of h along +theta_o at right angles to n'
            sin_h = np.sqrt(oy2 + t * t)
            x = np.minimum(sin_h * inv_h, 1.0) * (2.0 * inv)
            wp = 0.5 + 0.5 * t / np.maximum(sin_h, 1e-300)
        else:
            sd, cd = math.sin(comp.offset), math.cos(comp.offset)
            if comp.kind == "forward":  # axis at theta_i + offset
                sa, ca = si * cd + ci * sd, ci * cd - si * sd
            elif comp.kind == "back":  # axis at -theta_i + offset
                sa, ca = ci * sd - si * cd, ci * cd + si * sd
            else:
                sa, ca = sd, cd
            dx, dz = ox - sa, oz - ca
            x = np.sqrt(dx * dx + oy2 + dz * dz) * inv  # chord |wo - axis| in grid steps
            t = oz * sa - ox * ca  # -(wo . e), e the in-plane unit vector at right angles to the axis
            sin_psi = np.sqrt(oy2 + t * t)
            wp = 0.5 - 0.5 * t / np.maximum(sin_psi, 1e-300)  # weight of side + (t = 0 on the axis itself)
        i0 = x.astype(np.intp)  # NaN rows (invalid input, discarded by eval) give any index: take clips
        fr = np.clip(x - i0, 0.0, 1.0)
        w[:, 0] = (1.0 - fr) * wp  # node i, side +
        w[:, 1] = (1.0 - fr) - w[:, 0]  # node i, side -
        w[:, 2] = fr * wp  # node i + 1, side +
        w[:, 3] = fr - w[:, 2]  # node i + 1, side -
        acc = np.einsum("nk,nkc->nc", w, np.take(comp.table, i0, axis=0, mode="clip"))
        cov = acc[:, c]
        ok = cov > (_COV_MIN if comp.kind == "diffuse" else _LOBE_MIN_COV)
        val = acc[:, :c] / np.maximum(cov, np.float32(1e-30))[:, None]
        if comp.kind != "diffuse":
            val *= np.minimum(cov + cov, np.float32(1.0))[:, None]  # fade out towards a side without data
        val *= ok[:, None]
        if comp.excess:  # back to f_r: undo the measurement's cosines, add the diffuse base below
            val /= np.maximum(ci * oz, comp.cmin if fwd is None else comp.cmin * fwd[0]).astype(np.float32)[:, None]
            if fwd is not None:
                val *= fwd[1].astype(np.float32)[:, None]
            if base is not None:
                val += base
        lum = val[:, 0].copy()
        for k in range(1, c):
            lum += val[:, k]
        lum[~ok] = -1.0
        geo.append((x, wp))
        if comp.kind == "diffuse" and ncomp > 1:
            # the base a forward excess stands on: this lobe, or its nearest data where it has none
            base = val.copy()
            if not ok.all():
                miss0 = ~ok
                k = np.clip(np.rint(x[miss0]).astype(np.intp), 0, comp.near.shape[0] - 1)
                base[miss0] = comp.near[k, 0, :c]
        if best is None:
            best, top = val, lum
        else:  # the thesis's merge: the highest luminance wins
            better = lum > top
            best = np.where(better[:, None], val, best)
            top = np.maximum(top, lum)
    assert best is not None and top is not None
    best = best.astype(np.float64)
    miss = top < 0
    if miss.any():
        if fill == "interpolate":
            # Inverse-distance average of the nearest edges of every lobe (the thesis's proposed improvement).
            m = int(miss.sum())
            num = np.zeros((m, c))
            dsum = np.zeros(m)
            for comp, (x, wp) in zip(model.comps, geo, strict=True):
                k = np.clip(np.rint(x[miss]).astype(np.intp), 0, comp.near.shape[0] - 1)
                nr = comp.near[k]  # (m, 2, C + 1)
                for s, w_side in ((0, wp[miss]), (1, 1.0 - wp[miss])):
                    ws = (w_side + 1e-3) / (nr[:, s, c] + 1e-4) ** 2
                    num += ws[:, None] * nr[:, s, :c]
                    dsum += ws
            best[miss] = num / dsum[:, None]
        else:
            best[miss] = 0.0  # the thesis: no solid there, no reflection
    return best * model.scale


def _canonical(wi: Array, wo: Array) -> tuple[Array, Array, Array, Array, Array, Array, Array]:
    """Turn each pair about the normal so that wi lies in the x-z plane on the -x side (isotropy).

    ``wi``, ``wo`` (n, 3), any length. Returns (above, sin theta_i, cos theta_i, wo'_x, wo'_y, wo'_z, rho_i)
    with wo' the unit outgoing direction in that frame; ``above`` marks pairs above the horizon. Rows with
    non-finite input come out NaN somewhere and are discarded by :meth:`RevolveReconstruction.eval`.
    """
    ix, iy, iz = np.ascontiguousarray(wi.T)  # contiguous columns: strided ones make every operation slower
    ox, oy, oz = np.ascontiguousarray(wo.T)
    rho2 = ix * ix + iy * iy
    inv_i = 1.0 / np.sqrt(rho2 + iz * iz)
    inv_o = 1.0 / np.sqrt(ox * ox + oy * oy + oz * oz)
    above = (iz > 0) & (oz > 0)
    rho = np.sqrt(rho2)
    flat = rho < 1e-300  # normal incidence: any frame will do
    inv = 1.0 / np.where(flat, 1.0, rho)
    ex = np.where(flat, inv_o, -ix * inv * inv_o)  # unit vector along the surface away from the light, / |wo|
    ey = -iy * inv * inv_o
    return above, rho * inv_i, iz * inv_i, ox * ex + oy * ey, oy * ex - ox * ey, oz * inv_o, rho


class RevolveReconstruction:
    """A full isotropic BRDF from solids of revolution (implements :class:`reconstruction.base.Reconstruction`).

    ``eval(wi, wo)`` gives f_r (N, C) in 1/sr; ``report()`` a JSON-serialisable description;
    ``hemisphere(theta_i_deg)`` the thesis's own merged solid for a measured incidence.
    """

    method = "revolve"
    #: theta_h (radians) below which the table holds theta_h cell averages (set when a peak is narrower than the
    #: instrument's cone: 1.5 times the widest plateau's theta_h), else None; and those plateaus
    sharp_theta_h_rad: float | None = None
    instrument_plateaus: list[dict[str, Any]] = []  # noqa: RUF012 - replaced per instance, never mutated

    @property
    def table_values(self) -> str:
        """What the table holds, for the report."""
        if self.sharp_theta_h_rad is None:
            return "bin centres"
        return (f"cell averages over theta_h below {math.degrees(self.sharp_theta_h_rad):.3g} deg (automatic: a "
                f"peak narrower than the instrument's cone), bin centres elsewhere")

    def __init__(self, incidences: list[_Incidence], models: list[_Model], channels: list[str],
                 params: dict[str, Any], notes: list[str]) -> None:
        self.channels = list(channels)
        self._incs = incidences
        self._models = models
        self._params = params
        self._notes = notes
        self._thetas = np.array([m.theta_i for m in models])
        self._hemi: dict[int, HemisphereMap] = {}
        last = models[-1]  # a narrow forward lobe beyond the last incidence: its cap there (see .grazing)
        fwd = [cm for cm in last.comps if cm.kind == "forward" and cm.excess]
        narrow = bool(fwd) and grazing.hwhm_deg(fwd[0].val, last.du) < grazing.NARROW_HWHM_DEG
        self._gains = grazing.held_gains(self._eval_last, last.theta_i) if narrow else None

    @property
    def incidences_deg(self) -> list[float]:
        """The measured incidences theta_i, degrees, increasing."""
        return [math.degrees(t) for t in self._thetas]

    def table(self) -> Array:
        """The MERL table (3, 90, 90, 180): the reciprocal average from one evaluation per cell
        (:func:`~reconstruction.core.merltable.tabulate_reciprocal`: every lobe is symmetric about the plane of
        incidence)."""
        from reconstruction.core import merltable

        recip = self._params.get("reciprocal", False)
        t = (merltable.tabulate_reciprocal(lambda i, o: self.eval(i, o, False)) if recip
             else merltable.tabulate(self.eval))
        return (merltable.average_theta_h_cells(self.eval, t, self.sharp_theta_h_rad, n=8)[0] if self.sharp_theta_h_rad
                else t)

    def eval(self, wi: ArrayLike, wo: ArrayLike, reciprocal: bool | None = None) -> Array:
        """f_r (..., C) in 1/sr at direction pairs (..., 3) (z = normal); 0 where either is below the horizon.

        Each pair is turned about the normal so that wi lies in the plane of incidence; every lobe is looked
        up at the angle from its axis for this incidence; between measured incidences the two neighbouring
        models are blended linearly in theta_i (outside their range the nearest one is used). ``reciprocal``:
        average f(wi, wo) and f(wo, wi) (default: as reconstructed).
        """
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        shape = np.broadcast_shapes(wi.shape, wo.shape)
        if shape[-1:] != (3,):
            raise ReconstructionError(f"eval expects direction arrays (..., 3), got {wi.shape} and {wo.shape}")
        wi = np.broadcast_to(wi, shape).reshape(-1, 3)
        wo = np.broadcast_to(wo, shape).reshape(-1, 3)
        n = wi.shape[0]
        out = np.empty((n, len(self.channels)))
        recip = self._params.get("reciprocal", False) if reciprocal is None else reciprocal
        for a in range(0, n, _EVAL_CHUNK):  # blocks that stay in cache, each vectorised
            i, o = wi[a:a + _EVAL_CHUNK], wo[a:a + _EVAL_CHUNK]
            out[a:a + _EVAL_CHUNK] = 0.5 * (self._eval_flat(i, o) + self._eval_flat(o, i)) if recip else \
                self._eval_flat(i, o)
        return out.reshape(shape[:-1] + (len(self.channels),))

    def _eval_flat(self, wi: Array, wo: Array) -> Array:
        """:meth:`eval` for flat (n, 3) arrays."""
        c = len(self.channels)
        with np.errstate(invalid="ignore", divide="ignore", over="ignore"):
            valid, si, ci, ox, oy, oz, rho = _canonical(wi, wo)
            th = self._thetas
            fill = self._params["fill"]
            ti = np.arctan2(rho, wi[:, 2])
            fwd = self._beyond(ti, ci, valid)
            if th.size == 1:
                res = _eval_model(self._models[0], ox, oy, oz, si, ci, fill, fwd)
            else:
                res = np.zeros((valid.size, c))
                k = np.clip(np.searchsorted(th, ti, side="right") - 1, 0, th.size - 2)
                t = np.clip((ti - th[k]) / (th[k + 1] - th[k]), 0.0, 1.0)
                for j in range(th.size - 1):  # one bracket of measured incidences at a time: a handful
                    sel = np.nonzero((k == j) & valid)[0]
                    if sel.size == 0:
                        continue
                    args = (ox[sel], oy[sel], oz[sel], si[sel], ci[sel], fill)
                    tj = t[sel, None]
                    lo = _eval_model(self._models[j], *args) if np.any(tj < 1) else 0.0
                    last = None if fwd is None or j < th.size - 2 else (fwd[0][sel], fwd[1][sel])
                    hi = _eval_model(self._models[j + 1], *args, last) if np.any(tj > 0) else 0.0
                    res[sel] = (1.0 - tj) * lo + tj * hi
        return np.where(valid[:, None] & (res > 0), res, 0.0)

    def _beyond(self, ti: Array, ci: Array, valid: NDArray[np.bool_]) -> tuple[Array, Array] | None:
        """(factor on the hold, gain) of the last model's narrow forward excess at incidences ``ti`` (radians), or None
        when no pair is beyond the last measured incidence or the lobe is broad (:mod:`.grazing`)."""
        out = valid & (ti > self._thetas[-1])
        if self._gains is None or not out.any():
            return None
        nodes, gains = self._gains
        return grazing.floor_scale(ci, float(self._thetas[-1])), np.where(out, np.interp(ti, nodes, gains), 1.0)

    def _eval_last(self, wi: Array, wo: Array, gain: float) -> Array:
        """The last measured incidence's model alone with its forward excess times ``gain`` (the hold scaled)."""
        valid, si, ci, ox, oy, oz, _ = _canonical(wi, wo)
        fwd = (grazing.floor_scale(ci, float(self._thetas[-1])), np.full(ci.shape, gain))
        res = _eval_model(self._models[-1], ox, oy, oz, si, ci, self._params["fill"], fwd)
        return np.where(valid[:, None] & (res > 0), res, 0.0)

    def hemisphere(self, theta_i_deg: float | None = None, *, resolution_deg: float = 1.0,
                   fill: str | None = None, upsample: bool = True) -> HemisphereMap:
        """The thesis's merged solid for a measured incidence (default the first); ``fill`` defaults to the
        reconstruction's own."""
        k = 0
        if theta_i_deg is not None:
            d = np.abs(np.degrees(self._thetas) - theta_i_deg)
            k = int(np.argmin(d))
            if d[k] > 1e-9:
                raise ReconstructionError(f"theta_i_deg = {theta_i_deg} was not measured; have "
                                          f"{', '.join(f'{x:g}' for x in self.incidences_deg)}")
        return _hemisphere_of(self._incs[k], resolution_deg, fill or self._params["fill"], upsample)

    def report(self) -> dict[str, Any]:
        """JSON-serialisable: method, parameters, per incidence the sub-curves (theta_o ranges, axis kind,
        interpretation), the lobes built from them, the coverage of the thesis's hemisphere map, notes."""
        incs = []
        for k, (inc, model) in enumerate(zip(self._incs, self._models, strict=True)):
            if k not in self._hemi:
                self._hemi[k] = _hemisphere_of(inc, 1.0, "zero", True)
            hm = self._hemi[k]
            incs.append({
                "theta_i_deg": round(math.degrees(inc.theta_i), 6),
                "samples": int(inc.theta_o.size),
                "theta_o_range_deg": [round(math.degrees(inc.theta_o[0]), 6),
                                      round(math.degrees(inc.theta_o[-1]), 6)],
                "blind_spot_rows_dropped": inc.n_removed,
                "negative_values_clipped": inc.n_clipped,
                "holes_deg": [list(h) for h in inc.holes_deg],
                "subcurves": _subcurve_report(inc),
                "lobes": [{"interpretation": cm.kind,
                           "axis": {"diffuse": "normal", "forward": "mirror direction",
                                    "back": "incident direction"}[cm.kind],
                           "axis_offset_deg": round(math.degrees(cm.offset), 4),
                           "subcurves": list(cm.subcurves)} for cm in model.comps],
                "hemisphere_map": {"resolution_deg": hm.resolution_deg, "coverage": round(hm.coverage, 6),
                                   "fill": "zero"},
            })
        return {
            "method": self.method,
            "channels": list(self.channels),
            "parameters": dict(self._params),
            "fill": self._params["fill"],
            "incidences": incs,
            "coverage": round(float(np.mean([i["hemisphere_map"]["coverage"] for i in incs])), 6),
            "notes": list(self._notes),
            **({"instrument": {"plateaus": self.instrument_plateaus}} if self.instrument_plateaus else {}),
        }


def reconstruct_revolve(slices: Slice, *, axis: str = "auto", smoothing: float = DEFAULT_SMOOTHING_DEG,
                        fill: str = "interpolate", min_turn_deg: float = DEFAULT_MIN_TURN_DEG,
                        lobe_axis: str = "semantic", forward_frame: str = "half", excess: bool = True,
                        reciprocal: bool = False, blind_spot_deg: float | None = None, sort: bool = False
                        ) -> RevolveReconstruction:
    """Reconstruct a full isotropic BRDF from in-plane slices by solids of revolution.

    ``slices``: f_r (quantity "brdf"; other quantities are converted) with 1 ("value") or 3 ("R", "G",
    "B") channels, one or more distinct theta_i >= 0, theta_o strictly increasing within each theta_i
    (``sort=True`` sorts them instead of raising).

    ``axis``: "vertical", "pca" or "auto" (diffuse arcs vertical, lobes their principal axis unless clearly
    more symmetric about the vertical): the thesis's solids (:meth:`RevolveReconstruction.hemisphere`, the
    report) and, with ``lobe_axis="measured"``, the lobes' axes. ``smoothing``: sigma in degrees of theta_o
    of the Gaussian applied to log(value) before the acceleration is computed (0 = the raw curve, as in the
    thesis); ``min_turn_deg``: the tangent turning a valley needs to count as a split. ``fill``:
    "interpolate" (holes in the slice, such as the blind spot, are bridged and directions no lobe covers are
    interpolated from the lobes' nearest edges) or "zero" (the thesis: no data -> 0). ``lobe_axis``:
    "semantic" revolves each lobe exactly about the normal / mirror direction / incident direction (the more
    accurate: measured 0.096 against 0.116 table error for Lambert + GGX from one slice), "measured" turns
    that axis by the sub-curve axis' offset from it (at most 15 deg). ``forward_frame``: "half" measures a
    forward lobe's angle from the mirror direction as 2 theta_h (the same in the measured plane, the
    microfacet lobe's own variable elsewhere), "mirror" as the plain angle. ``excess``: a forward lobe keeps
    its excess over the diffuse lobe weighted by cos(theta_i) cos(theta_o) (nearly incidence-independent
    for microfacet lobes); False revolves f itself. ``reciprocal``: average f(wi, wo) and f(wo, wi)
    (reciprocal by construction, twice the eval time; the measured slice is then no longer reproduced
    exactly). ``blind_spot_deg``: drop every sample within this many degrees of the retro direction; None
    drops only rows of zeros within 10 deg of it (an export's blind spot), 0 drops nothing.
    """
    if axis not in _AXIS_KINDS:
        raise ReconstructionError(f"axis must be one of {', '.join(_AXIS_KINDS)}, got {axis!r}")
    if fill not in _FILLS:
        raise ReconstructionError(f"fill must be one of {', '.join(_FILLS)}, got {fill!r}")
    if lobe_axis not in _LOBE_AXES:
        raise ReconstructionError(f"lobe_axis must be one of {', '.join(_LOBE_AXES)}, got {lobe_axis!r}")
    if forward_frame not in ("half", "mirror"):
        raise ReconstructionError(f"forward_frame must be 'half' or 'mirror', got {forward_frame!r}")
    if not (math.isfinite(smoothing) and smoothing >= 0):
        raise ReconstructionError(f"smoothing must be a finite number of degrees >= 0, got {smoothing}")
    if not (math.isfinite(min_turn_deg) and min_turn_deg >= 0):
        raise ReconstructionError(f"min_turn_deg must be a finite number of degrees >= 0, got {min_turn_deg}")
    slices, plateaus = hold_peaks_over_cone(slices)  # a peak narrower than the instrument's cone keeps its energy
    incs, notes = _prepare(slices, sort, blind_spot_deg, bridge=fill == "interpolate")
    if fill == "interpolate":
        notes += _lend_peaks(incs)
    if plateaus:
        notes.append("peak narrower than the instrument's cone at theta_i = "
                     + ", ".join(f"{p['theta_i_deg']:g}" for p in plateaus)
                     + " deg: the mirror reading held over the cone (plateau samples added)")
    models = []
    for inc in incs:  # one model per measured incidence
        _analyse(inc, axis, smoothing, min_turn_deg)
        models.append(_build_model(inc, fill, lobe_axis, forward_frame, excess))
    if len(incs) == 1:
        notes.append("one incidence: lobe shapes are the same at every theta_i (only their axes move)")
    params = {"axis": axis, "smoothing_deg": smoothing, "min_turn_deg": min_turn_deg, "fill": fill,
              "lobe_axis": lobe_axis, "forward_frame": forward_frame, "excess": excess,
              "reciprocal": reciprocal, "blind_spot_deg": blind_spot_deg, "sort": sort}
    rec = RevolveReconstruction(incs, models, list(slices.channels), params, notes)
    if plateaus:  # the table holds theta_h cell averages around the plateaus (see RevolveReconstruction)
        rec.instrument_plateaus = plateaus
        rec.sharp_theta_h_rad = 0.75 * math.radians(max(p["plateau_half_width_deg"] for p in plateaus))
    return rec


def revolve_table(slices: Slice, **kwargs: Any) -> Array:
    """Slice -> :func:`reconstruct_revolve` -> MERL table (3, 90, 90, 180) at the bin centres (benchmarks)."""
    from reconstruction.core import merltable

    return merltable.tabulate(reconstruct_revolve(slices, **kwargs).eval)
