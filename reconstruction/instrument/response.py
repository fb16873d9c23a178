"""The instrument's angular response: what an in-plane reading of a BRDF really is (docs/instrument.md).

A detector of acceptance ``Omega`` (a cone of half angle ``a``, ``Omega = 2 pi (1 - cos a)``) about the nominal
direction ``wo_c`` collects ``int f(wi, wo) cos(theta_o) d omega_o`` over its cone; a calibrated reading divides by
``Omega cos(theta_o_c)``, so that it equals f at the centre for a smooth BRDF. A source of divergence ``s`` (half
angle) averages this over the beam's directions, uniformly in solid angle.

:func:`instrument_average` computes that reading. Smooth parts use a fixed polar Gauss rule over the cone; each
microfacet lobe (``reconstruction.core.models.Microfacet``) is integrated with a rule centred on its peak (the mirror
direction), in gnomonic coordinates about the cone's centre where the cone is an exact disk: rays from the peak,
each cut exactly at the disk's edge, with radial nodes spaced by the lobe's own (GGX slope) distribution. So a
lobe far narrower than the cone (ggx alpha 1e-3 in a 1 deg cone) is integrated to well under 1 % with a few hundred
evaluations, wherever its peak falls (inside, at the edge or outside the cone).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterator, Mapping, Sequence
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from functools import lru_cache
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.core.geometry import inplane_to_dirs, normalize
from reconstruction.core.models import Colour, Material, Microfacet
from reconstruction.schema.slice_meta import check_instrument

Array = NDArray[np.float64]
BrdfFn = Callable[[Array, Array], Array]

__all__ = ["Instrument", "InstrumentError", "instrument_average", "instrument_average_dirs", "unit_lobe_averages",
           "unit_lobe_tables", "shared_cone_averages", "shared_cone_entries", "seed_shared_cone_averages"]


# Quadrature sizes: the smooth polar rule (radial Gauss in r^2 x uniform azimuth), the lobe rule (rays x radial
# nodes) and the source rule (used only when the source diverges).
_SMOOTH_NR, _SMOOTH_NPHI = 4, 12
_LOBE_NPSI, _LOBE_NS = 24, 16
_SOURCE_NR, _SOURCE_NPHI = 2, 6
#: A microfacet lobe whose mirror direction lies more than this many cone half angles from the cone's centre is
#: integrated by the smooth rule (measured: within 2e-4 of a brute-force integral at 4, 0 at 6, alpha 1e-3..1e-2).
_NEAR_CONES = 6.0


class InstrumentError(ValueError):
    """An instrument description is invalid; the message names the key."""


@dataclass(frozen=True)
class Instrument:
    """The optics of a bench as a reconstruction needs them.

    ``detector_solid_angle_sr``: the detector cone's acceptance (sr; 0 = a point detector).
    ``source_divergence_deg``: the beam's half angle of divergence (deg; 0 = collimated).
    ``beam_diameter_mm`` / ``sample_diameter_mm``: the beam at normal incidence and the sample (mm; None = unknown).
    ``band``: what the value channels are: "rgb", "spectral" or e.g. "silicon x halogen-3000K" (one
    responsivity-weighted channel).
    """

    detector_solid_angle_sr: float = 0.0
    source_divergence_deg: float = 0.0
    beam_diameter_mm: float | None = None
    sample_diameter_mm: float | None = None
    band: str = "rgb"

    def __post_init__(self) -> None:
        # the same checks as from_meta, so that a bad value never gets as far as the integration
        self._check(self.to_meta(), "instrument")

    @staticmethod
    def _check(d: Mapping[str, Any], where: str) -> dict[str, Any]:
        try:
            return check_instrument(d, where)
        except ValueError as e:
            raise InstrumentError(str(e)) from None

    @property
    def aperture_half_angle_deg(self) -> float:
        """The detector cone's half angle (deg): degrees(acos(1 - Omega / (2 pi)))."""
        return math.degrees(math.acos(1.0 - self.detector_solid_angle_sr / (2.0 * math.pi)))

    @property
    def is_point(self) -> bool:
        """True for a point detector and a collimated source (a reading is f at the centre)."""
        return self.detector_solid_angle_sr == 0.0 and self.source_divergence_deg == 0.0

    @classmethod
    def from_half_angle(cls, half_angle_deg: float, **kw: Any) -> Instrument:
        """An instrument whose detector cone has this half angle (deg)."""
        return cls(2.0 * math.pi * (1.0 - math.cos(math.radians(half_angle_deg))), **kw)

    @classmethod
    def from_meta(cls, d: Mapping[str, Any] | None, where: str = "instrument") -> Instrument:
        """From the slice metadata's ``instrument`` object; None (a file of an earlier version) = a point instrument.

        Raises :class:`InstrumentError` naming the key when a value is malformed; unknown keys are ignored.
        """
        if d is None:
            return cls()
        return cls(**cls._check(d, where))

    def to_meta(self) -> dict[str, Any]:
        """The slice metadata's ``instrument`` object (every key, None as null)."""
        return {"detector_solid_angle_sr": self.detector_solid_angle_sr,
                "source_divergence_deg": self.source_divergence_deg,
                "beam_diameter_mm": self.beam_diameter_mm, "sample_diameter_mm": self.sample_diameter_mm,
                "band": self.band}


# --- quadrature helpers ----------------------------------------------------------------------------------------


@lru_cache(maxsize=32)
def _leggauss(n: int) -> tuple[Array, Array]:
    """Gauss-Legendre nodes and weights on [-1, 1] (computed once per n: the simulator asks for them per reading)."""
    x, w = np.polynomial.legendre.leggauss(n)
    x.setflags(write=False)
    w.setflags(write=False)
    return x, w


def _gauss01(n: int) -> tuple[Array, Array]:
    x, w = _leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


def _frame(wc: Array) -> tuple[Array, Array]:
    """Two unit vectors (m, 3) completing ``wc`` (m, 3) to an orthonormal frame."""
    helper = np.where(np.abs(wc[:, 1:2]) < 0.9, np.array([0.0, 1.0, 0.0]), np.array([1.0, 0.0, 0.0]))
    u = normalize(np.cross(helper, wc))
    v = np.cross(wc, u)
    return u, v


def _dirs(wc: Array, u: Array, v: Array, qx: Array, qy: Array) -> tuple[Array, Array]:
    """Directions for gnomonic coordinates (qx, qy) (m, k) about ``wc``, and d omega / (dqx dqy)."""
    d = wc[:, None, :] + qx[..., None] * u[:, None, :] + qy[..., None] * v[:, None, :]
    r2 = 1.0 + qx * qx + qy * qy
    return d / np.sqrt(r2)[..., None], r2 ** -1.5


def _smooth_nodes(tan_a: Array, nr: int, nphi: int) -> tuple[Array, Array, Array]:
    """A polar Gauss rule on the disk |q| <= tan_a (m,): (qx, qy, weight) each (m, nr * nphi), weights in sr."""
    x, w = _gauss01(nr)
    phi = (np.arange(nphi) + 0.5) * (2.0 * np.pi / nphi)
    r = tan_a[:, None, None] * np.sqrt(x)[None, :, None]  # (m, nr, 1)
    qx = (r * np.cos(phi)).reshape(len(tan_a), -1)
    qy = (r * np.sin(phi)).reshape(len(tan_a), -1)
    area = (0.5 * tan_a[:, None, None] ** 2 * w[None, :, None] * (2.0 * np.pi / nphi)) * np.ones((1, 1, nphi))
    area = area.reshape(len(tan_a), -1)
    return qx, qy, area * (1.0 + qx * qx + qy * qy) ** -1.5


def _slope(wi: Array, wc: Array, u: Array, v: Array, qx: Array, qy: Array) -> tuple[Array, Array]:
    """The microfacet slope (h_x / h_z, h_y / h_z) of the half vector between ``wi`` and the direction at q."""
    d, _ = _dirs(wc, u, v, qx, qy)
    h = wi[:, None, :] + d
    hz = np.maximum(h[..., 2], 1e-300)
    return h[..., 0] / hz, h[..., 1] / hz


def _lobe_nodes(wi: Array, wc: Array, u: Array, v: Array, tan_a: float, alpha: float, npsi: int = _LOBE_NPSI,
                ns: int = _LOBE_NS) -> tuple[Array, Array, Array, Array, Array]:
    """Peak-centred rule for a microfacet lobe of width ``alpha`` over the disk |q| <= tan_a.

    Returns (qx, qy, weight (m, npsi * ns) in sr, ok (m,), edge (m,)): ``ok`` is False where the mirror direction
    lies behind the cone's plane (the lobe is then smooth over the cone and the smooth rule takes it); ``edge`` is
    True where the peak lies inside the disk near its edge (the chord length then varies fast with the ray's angle
    and the caller asks for more rays).
    """
    m = len(wi)
    wr = wi * np.array([-1.0, -1.0, 1.0])
    cz = np.sum(wr * wc, axis=-1)
    ok = cz > 0.05
    czs = np.where(ok, cz, 1.0)
    px = np.sum(wr * u, axis=-1) / czs
    py = np.sum(wr * v, axis=-1) / czs
    # the slope's linear map at the peak -> the lobe's width along each ray (GGX slope scale alpha / |J e|)
    eps = 1e-6 * max(tan_a, 1e-6)
    with np.errstate(over="ignore", invalid="ignore"):
        jx = np.stack(_slope(wi, wc, u, v, (px + eps)[:, None], py[:, None]), axis=-1)[:, 0, :] / eps
        jy = np.stack(_slope(wi, wc, u, v, px[:, None], (py + eps)[:, None]), axis=-1)[:, 0, :] / eps
    # a light at or below the horizon has no microfacet peak to follow: the smooth rule takes it
    good = (wi[:, 2] > 1e-6) & np.all(np.isfinite(jx) & np.isfinite(jy), axis=1) & (np.abs(jx).max(1) < 1e12) & (
        np.abs(jy).max(1) < 1e12)
    ok &= good
    jx = np.where(good[:, None], jx, np.array([1.0, 0.0]))
    jy = np.where(good[:, None], jy, np.array([0.0, 1.0]))
    dist = np.hypot(px, py)
    inside = dist < tan_a
    # Rays are spaced uniformly in the slope plane, where the lobe is round (to first order): a ray at slope angle
    # chi leaves the peak along e = J^-1 (cos chi, sin chi), and d psi / d chi = |det J^-1| / |J^-1 (cos, sin)|^2.
    det = jx[:, 0] * jy[:, 1] - jy[:, 0] * jx[:, 1]
    det = np.where(np.abs(det) > 1e-300, det, 1e-300)
    inv = np.stack([np.stack([jy[:, 1], -jy[:, 0]], -1), np.stack([-jx[:, 1], jx[:, 0]], -1)], -2) / det[:, None,
                                                                                                          None]
    def to_chi(ang: Array) -> Array:
        cx = jx[:, 0] * np.cos(ang) + jy[:, 0] * np.sin(ang)
        cy = jx[:, 1] * np.cos(ang) + jy[:, 1] * np.sin(ang)
        return np.arctan2(cy, cx)

    j = np.arange(npsi)
    # a peak inside the disk: all slope angles (more rays when the peak is near the edge, see _cone_reading)
    chi_in = np.broadcast_to((j + 0.5) * (2.0 * np.pi / npsi), (m, npsi))
    wchi_in = np.full((m, npsi), 2.0 * np.pi / npsi)
    # a peak outside the disk: the fan of rays that meets it, psi_c +- delta, as an arc of slope angles
    xg, wg = _leggauss(npsi)
    delta = np.arcsin(np.clip(tan_a / np.maximum(dist, 1e-300), 0.0, 1.0))
    centre = np.arctan2(-py, -px)

    chi_c = to_chi(centre)
    lo = np.mod(to_chi(centre - delta) - chi_c + np.pi, 2.0 * np.pi) - np.pi
    hi = np.mod(to_chi(centre + delta) - chi_c + np.pi, 2.0 * np.pi) - np.pi
    mid, half = 0.5 * (lo + hi), 0.5 * (hi - lo)
    chi_out = (chi_c + mid)[:, None] + half[:, None] * np.sin(0.5 * np.pi * xg)[None, :]
    wchi_out = np.abs(half)[:, None] * (0.5 * np.pi) * np.cos(0.5 * np.pi * xg)[None, :] * wg[None, :]
    chi = np.where(inside[:, None], chi_in, chi_out)
    wchi = np.where(inside[:, None], wchi_in, wchi_out)
    gx = inv[:, None, 0, 0] * np.cos(chi) + inv[:, None, 0, 1] * np.sin(chi)
    gy = inv[:, None, 1, 0] * np.cos(chi) + inv[:, None, 1, 1] * np.sin(chi)
    g2 = np.maximum(gx * gx + gy * gy, 1e-300)
    psi = np.arctan2(gy, gx)
    wpsi = wchi * np.abs(1.0 / det)[:, None] / g2
    ex, ey = np.cos(psi), np.sin(psi)
    b = px[:, None] * ex + py[:, None] * ey
    c = (dist * dist - tan_a * tan_a)[:, None]
    root = np.sqrt(np.maximum(b * b - c, 0.0))
    s0 = np.where(inside[:, None], 0.0, np.maximum(-b - root, 0.0))
    s1 = np.maximum(-b + root, s0)
    je = np.hypot(jx[:, None, 0] * ex + jy[:, None, 0] * ey, jx[:, None, 1] * ex + jy[:, None, 1] * ey)
    beta = np.clip(alpha / np.maximum(je, 1e-300), 1e-9, 10.0)  # (m, npsi)
    u0 = s0 * s0 / (beta * beta + s0 * s0)
    u1 = s1 * s1 / (beta * beta + s1 * s1)
    t, wt = _gauss01(ns)
    uu = u0[..., None] + (u1 - u0)[..., None] * t  # (m, npsi, ns)
    om = np.maximum(1.0 - uu, 1e-150)
    s = beta[..., None] * np.sqrt(uu / om)
    ws = (u1 - u0)[..., None] * wt * beta[..., None] ** 2 / (2.0 * om * om)  # = s ds
    qx = (px[:, None, None] + s * ex[..., None]).reshape(m, -1)
    qy = (py[:, None, None] + s * ey[..., None]).reshape(m, -1)
    w = (wpsi[..., None] * ws).reshape(m, -1) * (1.0 + qx * qx + qy * qy) ** -1.5
    return qx, qy, w, ok, inside & (dist > 0.8 * tan_a)


# --- the reading -----------------------------------------------------------------------------------------------


def _split(f: BrdfFn | Material, lobes: Sequence[Microfacet] | None
           ) -> tuple[BrdfFn, list[Microfacet], int, Array | None]:
    """(the smooth rest, the microfacet lobes, channels or 0, wavelengths) of a BRDF."""
    mat = f if isinstance(f, Material) else getattr(f, "__self__", None)
    if lobes is None and isinstance(mat, Material) and getattr(f, "__func__", Material.eval) is Material.eval:
        mf = [lb for lb in mat.lobes if isinstance(lb, Microfacet)]
        others = [lb for lb in mat.lobes if not isinstance(lb, Microfacet)]
        n, wl = mat.n_channels, mat.wavelengths_nm

        def rest(wi: Array, wo: Array) -> Array:
            out = np.zeros(np.broadcast_shapes(wi.shape, wo.shape)[:-1] + (n,))
            for lb in others:
                out += lb.eval(wi, wo, n, wl)
            return out

        return rest, mf, n, wl
    if isinstance(f, Material):
        f = f.eval
    mf = list(lobes or [])
    wl = getattr(mat, "wavelengths_nm", None)
    if not mf:
        return f, [], 0, wl

    def rest_sub(wi: Array, wo: Array) -> Array:
        out = np.array(f(wi, wo), dtype=np.float64)
        for lb in mf:
            out = out - lb.eval(wi, wo, out.shape[-1], wl if wl is not None else lb.colour.wavelengths_nm)
        return out

    return rest_sub, mf, 0, wl


def _smooth_lobe(lb: Microfacet, wib: Array, d: Array, idx: NDArray[np.bool_], n: int, lwl: Array | None,
                 geo: dict[str, tuple[Array, ...]]) -> Array:
    """``lb.eval(wib[idx], d[idx], n, lwl)``, the lobe at the smooth rule's nodes, with the half-vector cosines
    (independent of the lobe) computed once per cone reading in ``geo`` and shared by every lobe."""
    if type(lb).shape is not Microfacet.shape:  # a lobe of its own shape: evaluated as it says
        return lb.eval(wib[idx], d[idx], n, lwl)
    if "cos" not in geo:
        h = normalize(wib + d)
        geo["cos"] = (h[..., 2], np.sum(wib * h, axis=-1), wib[..., 2], d[..., 2])
    s = lb.shape_cosines(*(c[idx] for c in geo["cos"]))
    return s[..., None] * lb.colour.on(n, lwl)


def _unit_cosines(wi: Array, d: Array) -> tuple[Array, Array, Array, Array]:
    """(cos theta_h, cos theta_d, cos theta_i, cos theta_o), each (r, k), from ``wi`` (r, 3) to the directions ``d``
    (r, k, 3): the half vector's cosines written out per component (a unit lobe's many peak-rule nodes: about twice
    as fast as the general form), shared by every lobe of one width."""
    hx, hy, hz = (wi[:, None, j] + d[..., j] for j in range(3))
    inv = 1.0 / np.maximum(np.sqrt(hx * hx + hy * hy + hz * hz), 1e-300)
    cos_d = (wi[:, None, 0] * hx + wi[:, None, 1] * hy + wi[:, None, 2] * hz) * inv
    return hz * inv, cos_d, np.broadcast_to(wi[:, None, 2], hz.shape), d[..., 2]


#: The peak rule's (rays, radial nodes): for the simulator's readings and :func:`instrument_average`, and for the
#: fits' tables of unit lobes (:func:`unit_lobe_averages`: within 1e-3 of the readings' largest value at 70 deg
#: incidence 0.4 deg from the mirror direction, the worst case of tests/test_instrument.py, at two thirds of the
#: cost; the fits interpolate those tables over alpha to about 2 %). Against a rule of 96 x 48 nodes the readings'
#: rule is within 2.3e-4 there.
READING_RULE = (_LOBE_NPSI, _LOBE_NS)
TABLE_RULE = (20, 12)


def _cone_reading(rest: BrdfFn, lobes: list[Microfacet], n_ch: int, wl: Array | None, wi: Array, wc: Array,
                  tan_a: float, per_lobe: bool = False, rule: tuple[int, int] = READING_RULE) -> Array:
    """(1 / Omega) int f cos(theta_o) d omega over the cone of half angle atan(tan_a) about ``wc``: (m, C); with
    ``per_lobe`` each microfacet lobe's own reading, channel 0, the smooth rest left out: (m, len(lobes)). ``rule``:
    the peak rule's (rays, radial nodes). Lobes of one width share the peak rule's nodes (they depend on alpha
    alone), so a table of several distributions costs little more than one."""
    m = len(wi)
    omega = 2.0 * np.pi * (1.0 - 1.0 / math.sqrt(1.0 + tan_a * tan_a))
    u, v = _frame(wc)
    ta = np.full(m, tan_a)
    qx, qy, w = _smooth_nodes(ta, _SMOOTH_NR, _SMOOTH_NPHI)
    d, _ = _dirs(wc, u, v, qx, qy)
    wib = np.broadcast_to(wi[:, None, :], d.shape)
    cosw = (w * np.maximum(d[..., 2], 0.0))[..., None]
    total = np.sum(np.asarray(rest(wib, d), dtype=np.float64) * cosw, axis=1)
    n = n_ch or total.shape[-1]
    # the mirror direction's angle from the cone's centre: a lobe whose peak lies beyond _NEAR_CONES cone radii is
    # smooth over the cone (the smooth rule is then within 1e-4 of a brute-force integral even at grazing angles)
    wr = wi * np.array([-1.0, -1.0, 1.0])
    near_peak = np.sum(wr * wc, axis=-1) > math.cos(min(_NEAR_CONES * math.atan(tan_a), 0.5 * math.pi))
    geo: dict[str, tuple[Array, ...]] = {}
    parts: list[Array | None] = [None] * len(lobes)
    peak: tuple[float, NDArray[np.bool_], list[list[Any]]] | None = None  # the last width's peak nodes
    npsi, ns = rule
    # per lobe, lobes of one width one after the other (a table of several distributions), each to its own column
    order = sorted(range(len(lobes)), key=lambda k: lobes[k].alpha) if per_lobe else range(len(lobes))
    for j in order:  # a handful (a table's few dozen)
        lb = lobes[j]
        acc = np.zeros_like(total) if per_lobe else total
        lwl = wl if wl is not None else lb.colour.wavelengths_nm
        unit = per_lobe and type(lb).shape is Microfacet.shape
        if peak is None or peak[0] != lb.alpha:
            peak = (lb.alpha, *_peak_nodes(wi, wc, u, v, tan_a, lb.alpha, near_peak, npsi, ns))
        sharp, groups = peak[1], peak[2]
        if np.any(~sharp):
            idx = ~sharp
            acc[idx] += np.sum(_smooth_lobe(lb, wib, d, idx, n, lwl, geo) * cosw[idx], axis=1)
        for g in groups:  # the peak rule where the lobe is narrow next to the cone, near its mirror direction
            r, ld, lcw = g[:3]
            if unit and g[3] is None:
                g[3] = _unit_cosines(wi[r], ld)
            val = (lb.shape_cosines(*g[3])[..., None] if unit
                   else lb.eval(np.broadcast_to(wi[r][:, None, :], ld.shape), ld, n, lwl))
            acc[r] += np.sum(val * lcw, axis=1)
        if per_lobe:
            parts[j] = acc[:, 0]
    if per_lobe:
        return np.stack(parts, axis=-1).reshape(m, len(lobes)) / omega
    return total / omega


def _peak_nodes(wi: Array, wc: Array, u: Array, v: Array, tan_a: float, alpha: float, near_peak: NDArray[np.bool_],
                npsi: int, ns: int) -> tuple[NDArray[np.bool_], list[list[Any]]]:
    """The peak rule of a lobe of width ``alpha``: (rows it takes (m,), and per group of rows [rows, node directions
    (r, k, 3), weights x cos theta_o (r, k, 1), None: the place of the half vector's cosines, filled by the first
    unit lobe that needs them (:func:`_unit_cosines`)]). A row takes
    it where the lobe is narrow next to the cone and its mirror direction near it (``near_peak``); a peak near the
    cone's edge gets four times the rays."""
    sharp = near_peak & (alpha / max(tan_a, 1e-300) < 2.0)
    groups: list[list[Any]] = []
    if not np.any(sharp):
        return sharp, groups
    lqx, lqy, lw, ok, edge = _lobe_nodes(wi[sharp], wc[sharp], u[sharp], v[sharp], tan_a, alpha, npsi, ns)
    sharp[sharp] = ok
    rows = np.flatnonzero(sharp)
    lqx, lqy, lw, edge = lqx[ok], lqy[ok], lw[ok], edge[ok]
    for sel, nodes in ((~edge, (lqx, lqy, lw)), (edge, None)):
        if not np.any(sel):
            continue
        r = rows[sel]
        if nodes is None:  # a peak near the cone's edge: four times the rays
            nodes = _lobe_nodes(wi[r], wc[r], u[r], v[r], tan_a, alpha, 4 * npsi, ns)[:3]
        else:
            nodes = tuple(a[sel] for a in nodes)
        ld, _ = _dirs(wc[r], u[r], v[r], nodes[0], nodes[1])
        lcw = (nodes[2] * np.maximum(ld[..., 2], 0.0))[..., None]
        groups.append([r, ld, lcw, None])
    return sharp, groups


def instrument_average(f: BrdfFn | Material, theta_i_deg: ArrayLike, theta_o_deg: ArrayLike,
                       instrument: Instrument, lobes: Sequence[Microfacet] | None = None) -> Array:
    """The reading (n, channels) that in-plane samples (theta_i, signed theta_o, deg, broadcast to (n,)) give.

    The integral of f cos(theta_o) over the detector's cone (and averaged over the source's divergence) divided by
    the cone's solid angle and by cos(theta_o) at the centre: f at the centre for a smooth BRDF. ``f`` is a BRDF
    callable f(wi, wo) -> (..., channels) in 1/sr (e.g. ``Material.eval``) or a Material; a material's microfacet
    lobes are found and integrated with a rule centred on their peak. For another callable, ``lobes`` names the
    microfacet lobes it contains (their sum is taken out of f and integrated that way); without them f must be
    smooth over the cone. A point instrument returns f at the centre.

    Examples
    --------
    >>> from reconstruction.core.models import Lambert, Colour
    >>> mat = Material("white", [Lambert(Colour(np.array([0.5])))])
    >>> r = instrument_average(mat.eval, [30.0], [10.0], Instrument.from_half_angle(1.0))
    >>> bool(np.allclose(r, 0.5 / np.pi))
    True
    """
    ti = np.radians(np.atleast_1d(np.asarray(theta_i_deg, dtype=np.float64)))
    to = np.radians(np.atleast_1d(np.asarray(theta_o_deg, dtype=np.float64)))
    ti, to = np.broadcast_arrays(ti, to)
    wi, wc = inplane_to_dirs(ti.ravel(), to.ravel())
    return instrument_average_dirs(f, wi, wc, instrument, lobes)


def instrument_average_dirs(f: BrdfFn | Material, wi: ArrayLike, wo: ArrayLike, instrument: Instrument,
                            lobes: Sequence[Microfacet] | None = None) -> Array:
    """:func:`instrument_average` for any direction pairs: unit vectors ``wi`` (to the light) and ``wo`` (the
    detector cone's centre), (n, 3) each; returns (n, channels)."""
    return _average_dirs(f, wi, wo, instrument, lobes)


def _average_dirs(f: BrdfFn | Material, wi: ArrayLike, wo: ArrayLike, instrument: Instrument,
                  lobes: Sequence[Microfacet] | None = None, per_lobe: bool = False,
                  rule: tuple[int, int] = READING_RULE) -> Array:
    """:func:`instrument_average_dirs`; with ``per_lobe`` (``f`` a material of microfacet lobes only) each lobe's
    reading, channel 0: (n, lobes). ``rule``: the peak rule's (rays, radial nodes)."""
    wi = np.atleast_2d(np.asarray(wi, dtype=np.float64))
    wc = np.atleast_2d(np.asarray(wo, dtype=np.float64))
    wi, wc = np.broadcast_arrays(wi, wc)
    wi, wc = wi.reshape(-1, 3), wc.reshape(-1, 3)
    m = len(wi)
    fn: BrdfFn = f.eval if isinstance(f, Material) else f
    if per_lobe:
        assert isinstance(f, Material) and all(isinstance(lb, Microfacet) for lb in f.lobes)
        fn = lambda a, b: np.stack([lb.eval(a, b, 1)[..., 0] for lb in f.lobes], axis=-1)  # noqa: E731
    if instrument.is_point or m == 0:
        out = np.asarray(fn(wi, wc), dtype=np.float64)
        return out.reshape(m, out.shape[-1] if out.ndim > 1 else 1)
    rest, mf, n_ch, wl = _split(f, lobes)
    half = math.radians(instrument.aperture_half_angle_deg)
    tan_a = math.tan(half)
    if instrument.source_divergence_deg > 0.0:
        # the beam's directions: a polar Gauss rule over the source cone, uniform in solid angle
        ts = math.tan(math.radians(instrument.source_divergence_deg))
        su, sv = _frame(wi)
        sqx, sqy, sw = _smooth_nodes(np.full(m, ts), _SOURCE_NR, _SOURCE_NPHI)
        wis, _ = _dirs(wi, su, sv, sqx, sqy)  # (m, k, 3)
        k = wis.shape[1]
        wis = wis.reshape(-1, 3)
        wcs = np.repeat(wc, k, axis=0)
        sw = sw / np.sum(sw, axis=1, keepdims=True)
    else:
        wis, wcs, k, sw = wi, wc, 1, np.ones((m, 1))
    if tan_a > 0.0:
        vals = _cone_reading(rest, mf, n_ch, wl, wis, wcs, tan_a, per_lobe, rule)
    else:
        vals = np.asarray(fn(wis, wcs), dtype=np.float64).reshape(len(wis), -1)
        vals = vals * np.maximum(wcs[:, 2:3], 0.0)
    vals = vals.reshape(m, k, -1)
    reading = np.sum(vals * sw[..., None], axis=1)
    cos_c = np.maximum(wc[:, 2], 1e-12)[:, None]
    return reading / cos_c


# --- unit lobes, shared ----------------------------------------------------------------------------------------

_SHARED: ContextVar[dict[Any, tuple[Array, Array]] | None] = ContextVar("shared_cone_averages", default=None)


@contextmanager
def shared_cone_averages() -> Iterator[None]:
    """Within this block :func:`unit_lobe_averages` remembers every direction pair's cone averages (per instrument,
    distribution and alpha grid) and computes only pairs it has not seen: ``auto`` refits on the folds of
    cross-validation subsets of the same samples, whose cone integrals are then computed once. Nested blocks share
    the outer memory; it is dropped when the outermost block ends."""
    if _SHARED.get() is not None:
        yield
        return
    token = _SHARED.set({})
    try:
        yield
    finally:
        _SHARED.reset(token)


def shared_cone_entries() -> dict[Any, tuple[Array, Array]]:
    """What the current :func:`shared_cone_averages` block holds ({key: (direction pairs (n, 6), readings)}; empty
    outside one): to send to another process's block (:func:`seed_shared_cone_averages`)."""
    return dict(_SHARED.get() or {})


def seed_shared_cone_averages(entries: Mapping[Any, tuple[Array, Array]]) -> None:
    """Add ``entries`` (:func:`shared_cone_entries` of another process) to the current block's memory: auto's forked
    child computes fit's tables while this process imports scipy. Outside a block, nothing happens."""
    memo = _SHARED.get()
    if memo is None:
        return
    for key, (pairs, vals) in entries.items():  # a few
        known = memo.get(key)
        memo[key] = (pairs, vals) if known is None else (np.concatenate([known[0], pairs]),
                                                         np.concatenate([known[1], vals]))


def unit_lobe_averages(wi: ArrayLike, wo: ArrayLike, instrument: Instrument, alphas: ArrayLike,
                       distribution: str = "ggx") -> Array:
    """The readings (n, len(alphas)) of unit microfacet lobes (colour 1, no Fresnel) of each roughness ``alphas``
    at the direction pairs ``wi``, ``wo`` (n, 3): column k is ``instrument_average_dirs`` of the material
    ``[Microfacet(alpha=alphas[k], distribution=distribution)]`` to within 1e-3 of the column's largest value
    (:data:`TABLE_RULE`), every lobe integrated in one pass over the quadrature's geometry. Inside
    :func:`shared_cone_averages`, pairs already computed are looked up. :func:`unit_lobe_tables` gives several
    distributions in one pass."""
    return unit_lobe_tables(wi, wo, instrument, alphas, (distribution,))[distribution]


def unit_lobe_tables(wi: ArrayLike, wo: ArrayLike, instrument: Instrument, alphas: ArrayLike,
                     distributions: Sequence[str] = ("ggx", "beckmann")) -> dict[str, Array]:
    """:func:`unit_lobe_averages` of each distribution, {distribution: (n, len(alphas))}: lobes of one width share
    the peak rule's nodes, so a second distribution costs about half the first."""
    wi = np.atleast_2d(np.asarray(wi, dtype=np.float64)).reshape(-1, 3)
    wo = np.atleast_2d(np.asarray(wo, dtype=np.float64)).reshape(-1, 3)
    al = np.atleast_1d(np.asarray(alphas, dtype=np.float64))
    dists = list(dict.fromkeys(distributions))
    memo = _SHARED.get()
    if memo is None or len(wi) == 0:
        return _compute_tables(wi, wo, instrument, al, dists)
    q = np.concatenate([wi, wo], axis=1)
    out: dict[str, Array] = {}
    todo: dict[str, tuple[Any, Array, Array, Array]] = {}
    for dn in dists:  # one or two
        key = (instrument, dn, al.tobytes(), TABLE_RULE)
        known, vals = memo.get(key, (np.zeros((0, 6)), np.zeros((0, al.size))))
        _, inv = np.unique(np.concatenate([known, q]), axis=0, return_inverse=True)
        inv = inv.reshape(-1)
        where = np.full(int(inv.max()) + 1, -1)
        where[inv[: len(known)]] = np.arange(len(known))
        hit = where[inv[len(known):]]
        out[dn] = np.empty((len(q), al.size))
        out[dn][hit >= 0] = vals[hit[hit >= 0]]
        todo[dn] = (key, known, vals, np.flatnonzero(hit < 0))
    miss = np.unique(np.concatenate([t[3] for t in todo.values()]))
    if miss.size:
        # a direction pair may repeat (repeated samples): compute each distinct pair once, every distribution that
        # misses one of them in the same pass
        uq, back = np.unique(q[miss], axis=0, return_inverse=True)
        at = np.full(len(q), -1)
        at[miss] = back.reshape(-1)  # each missing pair's row of uq
        need = [dn for dn in dists if todo[dn][3].size]
        new = _compute_tables(uq[:, :3], uq[:, 3:], instrument, al, need)
        for dn in need:  # each distribution takes (and keeps) only the pairs it did not know
            key, known, vals, own = todo[dn]
            out[dn][own] = new[dn][at[own]]
            rows = np.unique(at[own])
            memo[key] = (np.concatenate([known, uq[rows]]), np.concatenate([vals, new[dn][rows]]))
    return out


def _compute_tables(wi: Array, wo: Array, instrument: Instrument, al: Array, dists: list[str]) -> dict[str, Array]:
    """{distribution: readings (n, len(al))} of unit lobes, every distribution and width in one pass."""
    mat = Material("unit", [Microfacet(Colour(np.ones(1)), alpha=float(x), distribution=dn) for dn in dists
                            for x in al])
    vals = _average_dirs(mat, wi, wo, instrument, per_lobe=True, rule=TABLE_RULE)
    vals = vals.reshape(len(wi), len(dists), al.size)
    return {dn: vals[:, k] for k, dn in enumerate(dists)}
