"""The ``bivariate`` method: f tabulated over (theta_h, theta_d), independent of phi_d, from in-plane slices.

An in-plane sample (theta_i, theta_o) has theta_h = |theta_o - theta_i| / 2 and theta_d = |theta_o + theta_i| / 2,
so the samples of one incidence lie on two lines of the (theta_h, theta_d) plane: the forward branch
(theta_o >= theta_i) on theta_d = theta_i + theta_h and the backward branch (theta_o <= theta_i, through the retro
direction) on theta_d = |theta_i - theta_h|. The reconstruction assumes f depends on (theta_h, theta_d) only
(isotropic and phi_d-independent, as in Romeiro et al. 2008):

1. the interpolated quantity is q = (f - floor) cos^P(theta_d): ``floor`` is each channel's 5th percentile of f
   over all samples (the diffuse level, kept constant), and the excess over it carries the factor cos^P theta_d.
   At the specular peak (theta_i = theta_o = theta_d) a microfacet lobe has f cos^2 theta_d = D F G1^2 / 4, so
   P = 2 holds the peak's microfacet content constant across theta_d, P > 2 adds a Fresnel-like rise and P < 2
   lets Smith shadowing win, as it does for broad lobes. ``cos_power=None`` (the default) chooses P from the
   data: 1.5 for a broad peak (half width at half maximum of 4.5 deg of theta_h or more); for a sharp one, where
   shadowing is negligible, 2.5 from one incidence and, with slices at several incidences, the P of (2, 2.5)
   that best predicts each incidence from the others (leave-one-incidence-out, relative RMSE of f cos cos). On the 48
   real MERL materials (benchmarks/bench_real_materials.py) this halves the table error of a fixed P = 1.5 from
   one slice, and on simulated lambert + ggx materials it keeps P = 1.5, which suits them. P = 0 interpolates f
   itself;
2. along each line, q is interpolated in theta_h between its samples linearly in log(q + delta) (delta = 1e-4 of
   the channel's largest q), so a specular peak falls off between two samples as a lobe does, not as a
   straight line that would overstate its energy several times; the blind spot around the retro direction and
   missing samples are filled from their neighbours (``fill="zero"`` instead sets f = 0 inside gaps wider than
   1.5 times the line's median sample spacing);
3. at a given theta_h, q is interpolated linearly in theta_d between the lines that reach that theta_h, and held
   constant beyond the outermost line; beyond every line's theta_h range, the lines' end values are used;
4. f = max(0, floor + q / cos^P(theta_d)).

The table is this function at every cell's (theta_h, theta_d), the same for all phi_d (bin centres), or the cell
average with ``merltable.tabulate(rec.eval, supersample=...)``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.base import ReconstructionError
from reconstruction.core import merlgrid, merltable
from reconstruction.core.geometry import half_diff_from_dirs, inplane_to_dirs
from reconstruction.core.slicedata import Slice
from reconstruction.instrument.response import Instrument, InstrumentError

Array = NDArray[np.float64]

__all__ = ["BivariateReconstruction", "reconstruct_bivariate", "inplane_half_diff"]

_CHUNK = 100_000


def inplane_half_diff(theta_i: ArrayLike, theta_o: ArrayLike) -> tuple[Array, Array]:
    """(theta_h, theta_d) of in-plane samples; radians in, radians out (signed theta_o, + = specular side)."""
    ti = np.asarray(theta_i, dtype=np.float64)
    to = np.asarray(theta_o, dtype=np.float64)
    return np.abs(to - ti) / 2.0, np.abs(to + ti) / 2.0


@dataclass
class _Line:
    """One measured line of the (theta_h, theta_d) plane: theta_d = |theta_i + sign * theta_h|."""

    theta_i: float  # radians
    sign: float  # +1 forward (specular side of the mirror), -1 backward (through the retro direction)
    th: Array  # (n,) increasing theta_h of the samples, radians
    q: Array  # (n, C) the interpolated quantity (f - floor) cos^P(theta_d)
    gap_mask_th: Array  # (m, 2) theta_h intervals treated as holes (fill="zero"), radians

    def position(self, th: Array) -> Array:
        return np.abs(self.theta_i + self.sign * th)


@dataclass
class BivariateReconstruction:
    """f(theta_h, theta_d) from measured lines; ``eval`` and a fast bin-centre ``table``."""

    lines: list[_Line]
    channels: list[str]
    floor: Array  # (C,) 1/sr
    cos_power: float = 2.0
    fill: str = "interpolate"
    info: dict[str, Any] = field(default_factory=dict)
    method: str = "bivariate"
    delta: Array | None = None  # (C,) offset of the log interpolation along theta_h (1/sr cos^P)
    cell_average_th: bool = False  # the table holds cell averages over theta_h (a peak narrower than the cells)

    def __post_init__(self) -> None:
        if self.delta is None:  # positive and above -min(q), so every sample is reproduced exactly
            self.delta = np.array([max(1e-300, 1e-4 * max(float(np.max(np.abs(ln.q[:, c]))) for ln in self.lines))
                                   + max(0.0, -min(float(np.min(ln.q[:, c])) for ln in self.lines))
                                   for c in range(len(self.channels))])

    def f_hd(self, theta_h: ArrayLike, theta_d: ArrayLike) -> Array:
        """f (M, C) in 1/sr at half/difference angles (radians, (M,)); vectorised, chunked for memory."""
        th = np.asarray(theta_h, dtype=np.float64).reshape(-1)
        td = np.asarray(theta_d, dtype=np.float64).reshape(-1)
        out = np.empty((th.size, len(self.channels)))
        # chunks of query points, each vectorised over (points x lines x channels): bounded to ~2e7 values
        chunk = int(max(256, min(_CHUNK, 2e7 // max(1, len(self.lines) * len(self.channels)))))
        for s in range(0, th.size, chunk):
            out[s:s + chunk] = self._f_hd(th[s:s + chunk], td[s:s + chunk])
        return out

    def _f_hd(self, th: Array, td: Array) -> Array:
        m, n_c, k = th.size, len(self.channels), len(self.lines)
        pos = np.empty((m, k))
        val = np.empty((m, k, n_c))
        inside = np.empty((m, k), dtype=bool)
        for j, ln in enumerate(self.lines):  # a few lines (two per incidence), each vectorised over queries
            thc = np.clip(th, ln.th[0], ln.th[-1])
            pos[:, j] = ln.position(thc)
            for c in range(n_c):
                d = float(self.delta[c])  # type: ignore[index]
                val[:, j, c] = np.exp(np.interp(thc, ln.th, np.log(ln.q[:, c] + d))) - d
            inside[:, j] = (th >= ln.th[0] - 1e-12) & (th <= ln.th[-1] + 1e-12)
            if self.fill == "zero" and ln.gap_mask_th.size:
                hole = np.any((th[:, None] > ln.gap_mask_th[None, :, 0]) & (th[:, None] < ln.gap_mask_th[None, :, 1]),
                              axis=1)
                val[hole, j, :] = np.nan  # a hole: f = 0 there, whatever the floor
        # lines reaching this theta_h are used; where none does, every line (at its clamped end) is
        use = inside | ~inside.any(axis=1, keepdims=True)
        t = td[:, None]
        below = np.where(use & (pos <= t), pos, -np.inf)
        above = np.where(use & (pos >= t), pos, np.inf)
        jb = np.argmax(below, axis=1)
        ja = np.argmin(above, axis=1)
        rows = np.arange(m)
        pb, pa = below[rows, jb], above[rows, ja]
        has_b, has_a = np.isfinite(pb), np.isfinite(pa)
        vb, va = val[rows, jb], val[rows, ja]
        span = np.where(has_a & has_b, pa - pb, 1.0)
        w = np.where(has_a & has_b & (span > 1e-12), (td - np.where(has_b, pb, 0.0)) / np.maximum(span, 1e-12), 0.0)
        w = np.where(has_b, w, 1.0)  # only lines above: take the nearest above
        w = np.where(has_a, w, 0.0)  # only lines below: take the nearest below
        q = (1.0 - w)[:, None] * np.where(has_b[:, None], vb, 0.0) + w[:, None] * np.where(has_a[:, None], va, 0.0)
        f = self.floor[None, :] + q / np.maximum(np.cos(td), 1e-6)[:, None] ** self.cos_power
        return np.maximum(np.nan_to_num(f, nan=0.0), 0.0)

    def eval(self, wi: Array, wo: Array) -> Array:
        """f_r (N, C) in 1/sr at unit direction pairs (N, 3); 0 below the horizon."""
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        th, _, td, _ = half_diff_from_dirs(wi, wo)
        v = self.f_hd(th, td).reshape(th.shape + (len(self.channels),))
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return np.where(up[..., None], v, 0.0)

    def table(self) -> Array:
        """MERL table (3, 90, 90, 180) at bin centres: f(theta_h, theta_d) repeated over phi_d; NaN below horizon.

        With ``cell_average_th`` (a plateau from the instrument, see :func:`reconstruct_bivariate`) each cell holds
        the average over its theta_h extent instead (:data:`CELL_SUBSAMPLES` sub-samples uniform in the index
        sqrt(theta_h), weighted by sin(theta_h) d theta_h as ``merltable.tabulate``'s cell averages), so the plateau's
        edge keeps its energy whichever cell it falls in."""
        th, td, _ = merlgrid.cell_angles()
        if self.cell_average_th:
            o = (np.arange(CELL_SUBSAMPLES) + 0.5) / CELL_SUBSAMPLES
            u = (np.arange(merlgrid.N_TH)[:, None] + o[None, :]) / merlgrid.N_TH  # (90, n)
            ths = u * u * (np.pi / 2)
            w = np.sin(ths) * u
            w = w / w.sum(axis=1, keepdims=True)
            a = np.broadcast_to(ths[:, None, :], (merlgrid.N_TH, merlgrid.N_TD, CELL_SUBSAMPLES))
            b = np.broadcast_to(td[0, :, 0][None, :, None], a.shape)
            g = self.f_hd(a.ravel(), b.ravel()).reshape(merlgrid.N_TH, merlgrid.N_TD, CELL_SUBSAMPLES, -1)
            g = np.einsum("hdsc,hs->hdc", g, w)
        else:
            a, b = np.broadcast_arrays(th[:, :, 0], td[:, :, 0])  # (90, 90)
            g = self.f_hd(a.ravel(), b.ravel()).reshape(merlgrid.N_TH, merlgrid.N_TD, -1)
        g = np.broadcast_to(g, (merlgrid.N_TH, merlgrid.N_TD, g.shape[-1] if g.shape[-1] == 3 else 3))
        out = np.broadcast_to(np.moveaxis(g, -1, 0)[..., None], merltable.SHAPE).copy()
        out[:, ~merlgrid.valid_mask()] = np.nan
        return out

    @property
    def table_values(self) -> str:
        """What :meth:`table` holds, for the report."""
        return ("cell averages over theta_h (automatic: a specular peak narrower than the instrument's cone)"
                if self.cell_average_th else "bin centres")

    def coverage(self) -> dict[str, float]:
        """Fractions of the table's (theta_h, theta_d) bins interpolated between two lines vs extrapolated."""
        th, td, _ = merlgrid.cell_angles()
        a, b = np.broadcast_arrays(th[:, :, 0], td[:, :, 0])
        a, b = a.ravel(), b.ravel()
        pos = np.stack([ln.position(np.clip(a, ln.th[0], ln.th[-1])) for ln in self.lines], axis=1)
        inside = np.stack([(a >= ln.th[0]) & (a <= ln.th[-1]) for ln in self.lines], axis=1)
        between = np.any(inside & (pos <= b[:, None]), axis=1) & np.any(inside & (pos >= b[:, None]), axis=1)
        return {"bins_between_measured_lines": round(float(between.mean()), 4),
                "bins_extrapolated": round(float(1.0 - between.mean()), 4)}

    def report(self) -> dict[str, Any]:
        return {"method": self.method,
                "parameters": {"lines": len(self.lines), "fill": self.fill, "cos_power": self.cos_power,
                               "floor": self.floor.tolist(),
                               "approximation": "f(theta_h, theta_d), phi_d-independent"},
                "coverage_half_diff": self.coverage(), **self.info}


def _gaps(th: Array) -> Array:
    """(m, 2) theta_h intervals between samples wider than 1.5 times the median spacing."""
    if th.size < 3:
        return np.empty((0, 2))
    d = np.diff(th)
    wide = d > 1.5 * np.median(d)
    return np.stack([th[:-1][wide], th[1:][wide]], axis=1)


#: sub-samples per theta_h cell when the table holds cell averages
CELL_SUBSAMPLES = 16
#: a measured peak is narrower than the instrument's cone when its neighbour on the line is this much lower
PLATEAU_RATIO = 4.0


def _plateau(ln: _Line, omega_sr: float) -> dict[str, Any] | None:
    """Hold the line's mirror-direction sample over the instrument's cone, in place: a reading there is the
    lobe's energy in the cone / (Omega cos theta_o), and f = that reading over theta_h < r, with
    4 cos(theta_d) pi r^2 = Omega (the cone's solid angle in half-vector terms), keeps that energy.
    Beyond r, the line falls to its first sample outside (log-linear back-extrapolation of the next two).
    None when the line's first sample is not at the mirror direction or the peak is not sharp."""
    th, q = ln.th, ln.q
    if th.size < 3 or th[0] > 1e-6:
        return None
    lum = q.sum(axis=1)
    if not lum[0] > PLATEAU_RATIO * max(float(lum[1]), 1e-300):
        return None
    r = math.sqrt(omega_sr / (4.0 * math.pi * max(math.cos(ln.theta_i), 1e-3)))
    keep = th > r * (1.0 + 1e-6)  # samples beyond the plateau (a wide cone at grazing may hide some)
    nxt = np.nonzero(keep)[0]
    if nxt.size == 0:
        return None
    k = int(nxt[0])
    if k + 1 < th.size and np.all(q[k] > 0) and np.all(q[k + 1] > 0):
        slope = (np.log(q[k]) - np.log(q[k + 1])) / (th[k + 1] - th[k])  # the tail's log decay per radian
        edge = q[k] * np.exp(np.maximum(slope, 0.0) * (th[k] - r))
    else:
        edge = q[k]
    edge = np.clip(edge, np.minimum(q[k], q[0]), q[0])
    ln.th = np.concatenate([[0.0, r, r * (1.0 + 1e-6)], th[keep]])
    ln.q = np.concatenate([q[:1], q[:1], edge[None, :], q[keep]])
    ln.gap_mask_th = _gaps(ln.th)
    return {"theta_i_deg": round(math.degrees(ln.theta_i), 6), "branch": "forward" if ln.sign > 0 else "backward",
            "plateau_theta_h_deg": round(math.degrees(r), 6), "peak_over_next": round(float(lum[0] / max(lum[1],
                                                                                                       1e-300)), 3),
            "samples_inside": int(np.sum(~keep)) - 1}


COS_POWERS = (1.5, 2.0, 2.5)
SHARP_HWHM_DEG = 4.5


def peak_half_width_deg(slices: Slice) -> float:
    """Half width at half maximum in theta_h (degrees) of the specular peak (channel mean, above the 5th
    percentile floor) at the incidence with the highest peak, from whichever branch falls below half the peak
    first; 90 when no incidence shows a measurable peak."""
    f, _ = slices.brdf()
    lum = f.mean(axis=1)
    floor = float(np.percentile(lum, 5.0))
    best: tuple[float, float] | None = None
    for t in np.unique(slices.theta_i_deg):  # a handful of incidences
        at = slices.theta_i_deg == t
        to, q = slices.theta_o_deg[at], lum[at] - floor
        k = int(np.argmin(np.abs(to - t)))
        if abs(to[k] - t) > 2.0 or q[k] <= 0:  # the mirror direction is not measured: no peak to measure
            continue
        widths = []
        for side in (to > to[k], to < to[k]):
            th = np.abs(to[side] - t) / 2.0
            order = np.argsort(th)
            below = np.nonzero(q[side][order] < 0.5 * q[k])[0]
            if below.size:
                widths.append(float(th[order][below[0]]))
        if widths and (best is None or q[k] > best[0]):
            best = (float(q[k]), min(widths))
    return best[1] if best else 90.0


def _held_out_error(slices: Slice, fill: str, cos_power: float, max_folds: int = 8) -> float:
    """Relative RMSE of f cos(theta_i) cos(theta_o) predicting each incidence (or, with more than ``max_folds``,
    each group of neighbouring incidences) from the others."""
    f, _ = slices.brdf()
    num = den = 0.0
    for group in np.array_split(np.unique(slices.theta_i_deg), min(max_folds, np.unique(slices.theta_i_deg).size)):
        out = np.isin(slices.theta_i_deg, group)
        rec = reconstruct_bivariate(slices.take(~out), fill=fill, cos_power=cos_power)
        wi, wo = inplane_to_dirs(np.radians(slices.theta_i_deg[out]), np.radians(slices.theta_o_deg[out]))
        c = (wi[:, 2] * wo[:, 2])[:, None]
        num += float(np.sum(((rec.eval(wi, wo) - f[out]) * c) ** 2))
        den += float(np.sum((f[out] * c) ** 2))
    return math.sqrt(num / den) if den > 0 else math.inf


def choose_cos_power(slices: Slice, fill: str = "interpolate") -> tuple[float, str]:
    """(P, why): the cos power of the module docstring's step 1 for ``slices``."""
    w = peak_half_width_deg(slices)
    sharp = w < SHARP_HWHM_DEG
    shape = (f"the peak's half width at half maximum is {w:.3g} deg of theta_h "
             f"({'<' if sharp else '>='} {SHARP_HWHM_DEG:g} deg: {'sharp' if sharp else 'broad'})")
    if not sharp:
        return COS_POWERS[0], shape
    if np.unique(slices.theta_i_deg).size >= 2:
        errs = [_held_out_error(slices, fill, p) for p in COS_POWERS[1:]]
        k = int(np.argmin(errs))
        figures = ", ".join(f"P = {p:g}: {e:.4f}" for p, e in zip(COS_POWERS[1:], errs, strict=True))
        return COS_POWERS[1 + k], shape + "; leave-one-incidence-out relative RMSE of f cos cos: " + figures
    return COS_POWERS[-1], shape + "; one incidence"


def reconstruct_bivariate(slices: Slice, *, fill: str = "interpolate", cos_power: float | None = None
                          ) -> BivariateReconstruction:
    """Build the bivariate reconstruction from ``slices`` (f_r or any quantity; converted to f_r first).

    ``fill``: "interpolate" (default) fills holes along each line linearly; "zero" leaves f = 0 in gaps.
    ``cos_power``: P of the interpolated quantity (f - floor) cos^P(theta_d), see the module docstring (None:
    chosen from the data by :func:`choose_cos_power`).
    """
    why_p = "given"
    if cos_power is None:
        if len(slices) < 2 or fill not in ("interpolate", "zero"):
            cos_power = COS_POWERS[0]
        else:
            cos_power, why_p = choose_cos_power(slices, fill)
    if fill not in ("interpolate", "zero"):
        raise ReconstructionError(f"fill must be 'interpolate' or 'zero', got {fill!r}")
    if not 0.0 <= cos_power <= 4.0:
        raise ReconstructionError(f"cos_power must lie in [0, 4], got {cos_power}")
    if len(slices) < 2:
        raise ReconstructionError(f"{slices.source}: {len(slices)} sample(s); bivariate needs at least 2")
    f, _ = slices.brdf()
    ti = np.radians(slices.theta_i_deg)
    to = np.radians(slices.theta_o_deg)
    floor = np.maximum(np.percentile(f, 5.0, axis=0), 0.0)
    lines: list[_Line] = []
    notes: list[str] = []
    for t in np.unique(ti):  # one pass per incidence (a handful)
        at = ti == t
        for sign, branch in ((1.0, at & (to >= t)), (-1.0, at & (to <= t))):
            if branch.sum() == 0:
                continue
            th, _ = inplane_half_diff(ti[branch], to[branch])
            order = np.argsort(th, kind="stable")
            ths, fs = th[order], f[branch][order]
            td = np.abs(t + sign * ths)
            lines.append(_Line(float(t), sign, ths, (fs - floor) * np.cos(td)[:, None] ** cos_power, _gaps(ths)))
        if at.sum() < 2:
            notes.append(f"theta_i = {np.degrees(t):g} deg has a single sample")
    channels = list(slices.channels)
    if f.shape[1] not in (1, 3):
        raise ReconstructionError(f"{slices.source}: bivariate works on 1 (grey) or 3 (RGB) channels, got "
                                  f"{f.shape[1]}; convert spectra with reconstruction.core.colour first")
    try:
        inst = Instrument.from_meta(slices.meta.get("instrument"))
    except InstrumentError as e:
        raise ReconstructionError(f"{slices.source}: metadata {e}") from None
    plateaus = [p for ln in lines if inst.detector_solid_angle_sr > 0
                and (p := _plateau(ln, inst.detector_solid_angle_sr)) is not None]
    info: dict[str, Any] = {"incidences_deg": np.unique(slices.theta_i_deg).tolist(), "cos_power_reason": why_p,
                            "holes": ("interpolated linearly along each measured line" if fill == "interpolate"
                                      else "gaps wider than 1.5 x the median spacing left at f = 0")}
    if plateaus:
        info["instrument"] = {
            "instrument": inst.to_meta(), "plateaus": plateaus,
            "note": ("the specular peak is narrower than the detector's cone at the incidences listed: each holds "
                     "its mirror-direction reading over the cone (theta_h < plateau_theta_h_deg), which keeps the "
                     "lobe's measured energy; the table holds cell averages over theta_h (automatic "
                     f"supersampling, {CELL_SUBSAMPLES} sub-samples per cell) so the plateau's edge keeps it too")}
        notes.append("peak narrower than the instrument's cone at theta_i = "
                     + ", ".join(f"{p['theta_i_deg']:g}" for p in plateaus if p["branch"] == "forward")
                     + " deg: table cells hold theta_h averages there")
    if notes:
        info["notes"] = notes
    return BivariateReconstruction(lines, channels, floor, cos_power, fill, info, cell_average_th=bool(plateaus))
