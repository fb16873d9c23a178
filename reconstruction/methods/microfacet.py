"""The ``microfacet`` method: a non-parametric microfacet BRDF fitted to in-plane slices.

Model (isotropic, reciprocal, energy-conserving by construction)::

    f(wi, wo) = rho / pi + ks F(theta_d) sum_j w_j D_j(h) G1_j(wi) G1_j(wo) / (4 cos theta_i cos theta_o)

* **D, the normal distribution, non-parametric**: a non-negative mixture (weights w_j summing to 1) over a
  dictionary of GGX distributions whose roughness spans ``alpha_min`` .. 1 evenly in log alpha. A positive
  scale mixture represents a sharp core and a long tail as measured (a Student-t-like tail, two populations of
  facets), is monotone in theta_h and interpolates between samples smoothly; ``alpha_min`` follows the data
  (as sharp as the samples allow: a quarter of the angular sample spacing in theta_h, never inside a gap that
  hides the mirror direction, see :func:`reconstruction.methods.fit.gap_bounds`). The tabulated D is in the report.
* **G from D**: each dictionary term carries the Smith shadowing of its own distribution, so the model is a
  convex combination of physically valid microfacet BRDFs (each reciprocal, each with albedo <= 1).
* **F from physics**: none (F = 1), a dielectric interface of index ``eta`` or a conductor of complex index
  ``eta + i kappa`` (exact unpolarised Fresnel equations), chosen by BIC; the index is fitted. One slice sees D
  and F only jointly (each sample lies on theta_d = theta_i +- theta_h): the physical form of F is what
  separates them, and each further incidence adds a line.
* **diffuse**: Lambert, ``rho`` per channel (<= 1); ``ks`` per channel (the specular colour, <= 1: an interface
  reflects at most its Fresnel reflectance, so a strong specular needs a high index or a conductor).

Fit: variable projection. For a Fresnel candidate, f is linear in (rho, ks w_j), so the weights come from
non-negative least squares on the luminance with weights 1 / sqrt(std^2 + (rel f)^2 + (floor peak)^2); the
index is found on a grid and refined with a bounded scalar (dielectric) or Nelder-Mead (conductor) search of
that NNLS residual. The colour then follows per channel (rho_c, ks_c) by NNLS with the shape fixed, under the
constraint rho_c + ks_c E(theta_i) <= 1 at every incidence (E: the specular shape's directional albedo), so the
directional albedo never exceeds 1.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray
from scipy.optimize import minimize, minimize_scalar, nnls

from reconstruction.base import ReconstructionError
from reconstruction.core.geometry import normalize
from reconstruction.core.models import ggx_d, ggx_g1_over_cos
from reconstruction.core.samples import sample_directions
from reconstruction.core.slicedata import Slice
from reconstruction.instrument.response import Instrument, InstrumentError, unit_lobe_averages

Array = NDArray[np.float64]

__all__ = ["fresnel", "MicrofacetReconstruction", "reconstruct_microfacet", "FRESNEL_KINDS"]

FRESNEL_KINDS = ("none", "dielectric", "conductor")
ALPHA_FLOOR, ALPHA_CEIL = 0.002, 1.0
N_ALPHAS = 24
ETA_RANGE = (1.05, 3.0)  # dielectric index
CONDUCTOR_ETA_RANGE, KAPPA_RANGE = (0.05, 6.0), (1.0, 10.0)  # metals absorb: kappa >= 1
ENERGY_THETA_I = np.radians(np.arange(0.0, 89.0, 4.0))
_REL, _FLOOR = 0.03, 1e-3
INSTRUMENT_ALPHA_FLOOR = 1e-4  # the dictionary's sharpest term when the slice's instrument has a finite aperture
NEAR_CONES = 15.0  # samples within this many cone half angles (or 3 deg) of a mirror direction use cone averages


def fresnel(cos_d: ArrayLike, kind: str, eta: float = 1.5, kappa: float = 0.0) -> Array:
    """Unpolarised Fresnel reflectance at ``cos_d`` = cos(theta_d) for ``kind`` none | dielectric | conductor."""
    c = np.clip(np.asarray(cos_d, dtype=np.float64), 1e-9, 1.0)
    if kind == "none":
        return np.ones_like(c)
    n = complex(eta, kappa if kind == "conductor" else 0.0)
    ct = np.sqrt(1.0 - (1.0 - c * c) / (n * n) + 0j)
    rs = (c - n * ct) / (c + n * ct)
    rp = (n * c - ct) / (n * c + ct)
    return np.clip(0.5 * (np.abs(rs) ** 2 + np.abs(rp) ** 2), 0.0, 1.0)


def _geometry(wi: Array, wo: Array) -> tuple[Array, Array, Array, Array, Array]:
    """(cos theta_h, cos theta_d, cos theta_i, cos theta_o, above-horizon mask) of direction pairs (..., 3)."""
    h = normalize(wi + wo)
    ch = h[..., 2]
    cd = np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0)
    ci, co = wi[..., 2], wo[..., 2]
    return ch, cd, np.clip(ci, 0.0, 1.0), np.clip(co, 0.0, 1.0), (ci > 0) & (co > 0)


def _basis(ch: Array, ci: Array, co: Array, alphas: Array) -> Array:
    """(..., J): D_j G1_j(wi) G1_j(wo) / (4 ci co) of each dictionary GGX, 1/sr (finite at grazing)."""
    return np.stack([ggx_d(ch, a) * ggx_g1_over_cos(ci, a) * ggx_g1_over_cos(co, a) / 4.0 for a in alphas],
                    axis=-1)


def _specular_albedo(theta_i: Array, alphas: Array, weights: Array, kind: str, eta: float, kappa: float,
                     n: int = 48) -> Array:
    """Directional albedo (n_theta,) of ks = 1 specular part, by importance sampling each GGX term's half vector
    (u = its CDF of D cos theta_h, Gauss-Legendre; azimuth by the midpoint rule)."""
    x, wx = np.polynomial.legendre.leggauss(n)
    u, wu = 0.5 * (x + 1.0), 0.5 * wx
    phi = (np.arange(2 * n) + 0.5) / (2 * n) * 2 * np.pi
    out = np.zeros(theta_i.size)
    for a, w in zip(alphas, weights, strict=True):  # only the terms the mixture uses
        if w <= 0:
            continue
        tan2 = a * a * u / (1.0 - u)
        cth = 1.0 / np.sqrt(1.0 + tan2)
        sth = np.sqrt(1.0 - cth * cth)
        hx, hz = sth[:, None] * np.cos(phi)[None], np.broadcast_to(cth[:, None], (n, 2 * n))
        for k, t in enumerate(theta_i):  # a few incidences
            c_d = -math.sin(t) * hx + math.cos(t) * hz
            woz = 2.0 * c_d * hz - math.cos(t)
            ok = (c_d > 0) & (woz > 0)
            g = ggx_g1_over_cos(np.full(1, math.cos(t)), a)[0] * ggx_g1_over_cos(np.clip(woz, 0, 1), a)
            val = np.where(ok, fresnel(c_d, kind, eta, kappa) * g * np.clip(woz, 0, None) * c_d / hz, 0.0)
            out[k] += w * float(np.sum(val * wu[:, None]) / (2 * n))
    return out


@dataclass
class MicrofacetReconstruction:
    """Result of :func:`reconstruct_microfacet`; ``eval`` gives f_r (N, C) in 1/sr."""

    alphas: Array  # (J,) the GGX dictionary
    weights: Array  # (J,) mixture weights of D, summing to 1
    fresnel_kind: str
    eta: float
    kappa: float
    rho: Array  # (C,) diffuse albedo
    ks: Array  # (C,) specular scale
    channels: list[str]
    info: dict[str, Any] = field(default_factory=dict)
    method: str = "microfacet"

    def specular_shape(self, wi: Array, wo: Array) -> Array:
        """F sum_j w_j D_j G1_j G1_j / (4 ci co) (...), 1/sr, for ks = 1; 0 below the horizon."""
        ch, cd, ci, co, _ = _geometry(wi, wo)
        return self._shape_cos(ch, cd, ci, co)

    def eval(self, wi: Array, wo: Array) -> Array:
        """f_r (N, C) in 1/sr at unit direction pairs (N, 3); 0 below the horizon."""
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        _, _, _, _, up = _geometry(wi, wo)
        s = self.specular_shape(wi, wo)
        return np.where(up[..., None], self.rho / np.pi + s[..., None] * self.ks, 0.0)

    def _shape_hd(self, theta_h: Array, theta_d: Array, ci: Array, co: Array) -> Array:
        """:meth:`specular_shape` from the half-diff angles (radians) and cos theta_i, cos theta_o (broadcast):
        D of theta_h only and F of theta_d only are evaluated on their own axes."""
        return self._shape_cos(np.cos(theta_h), np.cos(theta_d), ci, co)

    def _shape_cos(self, ch: Array, cd: Array, ci: Array, co: Array) -> Array:
        """The specular shape from cos theta_h, cos theta_d, cos theta_i, cos theta_o (broadcast); 0 where theta_i
        or theta_o is at or below the horizon."""
        use = self.weights > 0
        up = (ci > 0) & (co > 0)
        ci, co = np.clip(ci, 0.0, 1.0), np.clip(co, 0.0, 1.0)
        s = np.zeros(np.broadcast_shapes(np.shape(ch), np.shape(cd), np.shape(ci), np.shape(co)))
        for a, w in zip(self.alphas[use], self.weights[use], strict=True):  # in place: table-sized arrays
            g = ggx_g1_over_cos(ci, a) * ggx_g1_over_cos(co, a)
            g *= w / 4.0 * ggx_d(ch, a)
            s += g
        s *= fresnel(cd, self.fresnel_kind, self.eta, self.kappa)
        s[~np.broadcast_to(up, s.shape)] = 0.0
        return s

    def table(self) -> Array:
        """The MERL table (3, 90, 90, 180): bin-centre values, and below :attr:`sharp_theta_h_rad` the cell averages
        over theta_h (:func:`reconstruction.core.halfdiff.average_theta_h_half_diff`, 8 per cell): the values of
        ``merltable.tabulate(eval)`` and ``merltable.average_theta_h_cells``, computed in the half-diff angles. NaN
        below the horizon."""
        from reconstruction.core import halfdiff, merlgrid

        th, td, _ = merlgrid.cell_angles()
        ci, co = merlgrid.cell_cosines()
        valid = (ci > 0) & (co > 0)  # merlgrid.valid_mask()
        rgb = self.rho if self.rho.size == 3 else np.repeat(self.rho[:1], 3)
        ks = self.ks if self.ks.size == 3 else np.repeat(self.ks[:1], 3)
        shape = self._shape_hd(th, td, ci, co)
        diffuse = np.ones_like(shape)
        sharp = self.sharp_theta_h_rad
        if sharp:
            rows, avg, covered = halfdiff.average_theta_h_half_diff(self._shape_hd, sharp, 8)
            shape[:rows] = np.where(valid[:rows], avg, shape[:rows])
            diffuse[:rows] = covered  # 0 for a cell whose sub-samples all lie below the horizon
        out = np.empty((3,) + shape.shape)
        for c in range(3):
            np.multiply(shape, ks[c], out=out[c])
            out[c] += diffuse * (rgb[c] / np.pi)
        out[:, ~valid] = np.nan
        return out

    @property
    def sharp_theta_h_rad(self) -> float | None:
        """theta_h (radians) below which the table holds theta_h cell averages (5 alpha of the sharpest term in
        use when it is under 0.01: a lobe narrower than the table's cells), else None."""
        used = self.alphas[self.weights > 1e-6]
        return 5.0 * float(used.min()) if used.size and used.min() < 0.01 else None

    @property
    def table_values(self) -> str:
        """What the table holds, for the report."""
        sharp = self.sharp_theta_h_rad
        return ("bin centres" if sharp is None else f"cell averages over theta_h below {math.degrees(sharp):.3g} "
                "deg (automatic: a lobe narrower than the table's cells), bin centres elsewhere")

    def ndf(self, theta_h: ArrayLike) -> Array:
        """The fitted normal distribution D(theta_h) (1/sr; normalised: integral of D cos theta_h = 1)."""
        ch = np.cos(np.asarray(theta_h, dtype=np.float64))
        return np.stack([ggx_d(ch, a) for a in self.alphas], axis=-1) @ self.weights

    def albedo(self, theta_i: ArrayLike = ENERGY_THETA_I) -> Array:
        """Directional albedo (n_theta, C) at incidences ``theta_i`` (radians)."""
        ti = np.atleast_1d(np.asarray(theta_i, dtype=np.float64))
        e = _specular_albedo(ti, self.alphas, self.weights, self.fresnel_kind, self.eta, self.kappa)
        return self.rho[None, :] + e[:, None] * self.ks[None, :]

    def analytic_lobes(self) -> list[dict[str, Any]]:
        """The model in the parameters schema's form (:class:`reconstruction.base.AnalyticLobes`): a lambert lobe
        and a ``ggx_mixture`` (the NDF's GGX terms and weights, the specular colour, the fitted Fresnel)."""
        use = self.weights > 0
        fres: dict[str, Any] = {"kind": self.fresnel_kind}
        if self.fresnel_kind != "none":
            fres["eta"] = self.eta
            fres["kappa"] = self.kappa if self.fresnel_kind == "conductor" else 0.0
        return [{"type": "lambert", "albedo": self.rho.tolist()},
                {"type": "ggx_mixture", "terms": [{"alpha": float(a), "weight": float(w)}
                                                  for a, w in zip(self.alphas[use], self.weights[use], strict=True)],
                 "specular": self.ks.tolist(), "fresnel": fres}]

    def report(self) -> dict[str, Any]:
        th = np.radians(np.array([0.0, 0.5, 1, 2, 5, 10, 20, 30, 45, 60, 75, 89]))
        used = self.weights > 1e-4
        return {"method": self.method,
                "parameters": {
                    "diffuse_albedo": self.rho.tolist(), "specular": self.ks.tolist(),
                    "fresnel": {"kind": self.fresnel_kind, "eta": self.eta,
                                "kappa": self.kappa if self.fresnel_kind == "conductor" else 0.0,
                                "f0": float(fresnel(1.0, self.fresnel_kind, self.eta, self.kappa))},
                    "ndf": {"representation": "non-negative mixture of GGX distributions",
                            "alpha": self.alphas[used].tolist(), "weight": self.weights[used].tolist(),
                            "theta_h_deg": np.degrees(th).round(3).tolist(),
                            "D_per_sr": self.ndf(th).tolist()}},
                **self.info}


def _alpha_min(s: Slice) -> tuple[float, str]:
    """The sharpest dictionary term the samples can resolve: a quarter of the finest outgoing spacing in theta_h,
    and no narrower than the gap around an unsampled mirror direction."""
    from reconstruction.methods.fit import gap_bounds

    steps = []
    for t in s.incidences():  # a handful
        to = np.unique(s.theta_o_deg[s.theta_i_deg == t])
        if to.size > 1:
            steps.append(float(np.median(np.diff(to))))
    step = min(steps) if steps else 2.0
    a_step = 0.25 * math.tan(math.radians(step / 2.0))
    a_gap = gap_bounds(s)["alpha_min"]
    a = max(ALPHA_FLOOR, a_step, a_gap)
    why = (f"{a:.4g}: a quarter of the {step:g} deg outgoing step in theta_h" if a == a_step else
           f"{a:.4g}: the gap around the mirror direction" if a == a_gap else f"{a:.4g}: the floor")
    return a, why


def _instrument(s: Slice, wi: Array, wo: Array) -> tuple[Instrument, NDArray[np.intp]]:
    """The slice's instrument and the samples near a mirror direction where it averages a sharp lobe."""
    try:
        inst = Instrument.from_meta(s.meta.get("instrument"))
    except InstrumentError as e:
        raise ReconstructionError(f"{s.source}: metadata {e}") from None
    if inst.is_point:
        return inst, np.zeros(0, dtype=np.intp)
    a = math.radians(inst.aperture_half_angle_deg) + math.radians(inst.source_divergence_deg)
    ang = np.arccos(np.clip(np.sum(wi * np.array([-1.0, -1.0, 1.0]) * wo, axis=-1), -1.0, 1.0))
    return inst, np.nonzero(ang < max(NEAR_CONES * a, math.radians(3.0)))[0]


def _weights(y: Array, std: Array) -> Array:
    peak = max(float(np.max(np.abs(y))), 1e-300)
    return 1.0 / np.sqrt(np.square(std) + np.square(_REL * y) + np.square(_FLOOR * peak))


def _solve(a: Array, y: Array, w: Array) -> tuple[Array, float]:
    x, r = nnls(a * w[:, None], y * w, maxiter=20 * a.shape[1])
    return x, float(r * r)


def _constrained_colour(cols: Array, f: Array, w: Array, e_spec: Array) -> tuple[float, float]:
    """(rho, ks) >= 0 minimising the weighted residual of rho/pi + ks S with rho + ks e_spec(theta) <= 1."""
    x, _ = _solve(cols, f, w)
    if x[0] <= 1.0 and x[1] <= 1.0 and x[0] + x[1] * float(np.max(e_spec)) <= 1.0:
        return float(x[0]), float(x[1])
    a, b = cols * w[:, None], f * w
    res = minimize(lambda z: float(np.sum((a @ z - b) ** 2)), np.array([min(x[0], 0.5), min(x[1], 0.5)]),
                   jac=lambda z: 2.0 * a.T @ (a @ z - b), method="SLSQP", bounds=[(0, 1), (0, 1)],
                   constraints=[{"type": "ineq", "fun": lambda z: 1.0 - z[0] - z[1] * e_spec,
                                 "jac": lambda z: -np.stack([np.ones_like(e_spec), e_spec], axis=1)}])
    z = np.maximum(res.x, 0.0)
    scale = 1.0 / max(1.0, float(np.max(z[0] + z[1] * e_spec)))  # exactly feasible whatever SLSQP's tolerance
    return float(z[0] * scale), float(z[1] * scale)


def reconstruct_microfacet(slices: Slice, *, fresnel_kinds: tuple[str, ...] = FRESNEL_KINDS,
                           n_alphas: int = N_ALPHAS) -> MicrofacetReconstruction:
    """Fit the non-parametric microfacet model to ``slices`` (f_r or any quantity; 1 or 3 channels)."""
    f, std = slices.brdf()
    n_c = f.shape[1]
    if n_c not in (1, 3):
        raise ReconstructionError(f"{slices.source}: microfacet works on 1 (grey) or 3 (RGB) channels, got {n_c}; "
                                  f"convert spectra with reconstruction.core.colour first")
    if len(slices) < 4:
        raise ReconstructionError(f"{slices.source}: {len(slices)} sample(s); microfacet needs at least 4")
    unknown = set(fresnel_kinds) - set(FRESNEL_KINDS)
    if unknown or not fresnel_kinds:
        raise ReconstructionError(f"fresnel kinds must be some of {', '.join(FRESNEL_KINDS)}, got {fresnel_kinds}")
    wi, wo = sample_directions(slices)  # in-plane, or anywhere for a DirectionalSlice (reconstruction.core.samples)
    ch, cd, ci, co, up = _geometry(wi, wo)
    a_min, a_why = _alpha_min(slices)
    inst, near = _instrument(slices, wi, wo)
    if near.size:  # the cone measures a narrower lobe's energy wherever its peak falls in it (if it is sampled)
        from reconstruction.methods.fit import gap_bounds

        a_gap = gap_bounds(slices)["alpha_min"]
        a_min = max(INSTRUMENT_ALPHA_FLOOR, a_gap)
        a_why = (f"{a_min:.4g}: the floor with a finite aperture (the readings are cone averages)"
                 if a_min > a_gap else f"{a_min:.4g}: the gap around the mirror direction")
    alphas = np.geomspace(a_min, ALPHA_CEIL, n_alphas)
    basis = np.where(up[:, None], _basis(ch, ci, co, alphas), 0.0)  # (N, J), computed once
    if near.size:  # a finite aperture: the dictionary terms as the cone reads them near the mirror directions
        basis[near] = unit_lobe_averages(wi[near], wo[near], inst, alphas)  # N_ALPHAS cone integrals of them
    lam = np.full((len(slices), 1), 1.0 / np.pi)
    y = f.mean(axis=1)
    w = _weights(y, std.mean(axis=1))

    def chi2(kind: str, eta: float, kappa: float) -> tuple[float, Array]:
        # a specular scale ks = sum of the weights above 1 would need F above what this interface reflects: the
        # index search is steered away from it (the colour step holds ks <= 1 exactly)
        a = np.concatenate([lam, basis * fresnel(cd, kind, eta, kappa)[:, None]], axis=1)
        x, r = _solve(a, y, w)
        excess = max(0.0, float(np.sum(x[1:])) - 1.0)
        return r * (1.0 + 100.0 * excess * excess), x

    results: dict[str, tuple[float, float, float, Array]] = {}
    for kind in fresnel_kinds:  # at most three families, each a small grid and a bounded refinement
        if kind == "none":
            r, x = chi2("none", 1.0, 0.0)
            results[kind] = (r, 1.0, 0.0, x)
        elif kind == "dielectric":
            grid = np.linspace(*ETA_RANGE, 12)
            e0 = float(grid[int(np.argmin([chi2(kind, e, 0.0)[0] for e in grid]))])
            opt = minimize_scalar(lambda e: chi2("dielectric", e, 0.0)[0], bounds=(max(ETA_RANGE[0], e0 - 0.2),
                                  min(ETA_RANGE[1], e0 + 0.2)), method="bounded", options={"xatol": 1e-3})
            e = float(opt.x)
            r, x = chi2(kind, e, 0.0)
            results[kind] = (r, e, 0.0, x)
        else:
            grid = [(e, k) for e in (0.2, 0.5, 1.0, 1.5, 2.0, 3.0) for k in (1.0, 2.0, 3.5, 5.0)]
            e0, k0 = grid[int(np.argmin([chi2(kind, e, k)[0] for e, k in grid]))]

            def obj(p: Array) -> float:
                e = float(np.clip(p[0], *CONDUCTOR_ETA_RANGE))
                k = float(np.clip(p[1], *KAPPA_RANGE))
                return chi2("conductor", e, k)[0]

            opt = minimize(obj, np.array([e0, k0]), method="Nelder-Mead",
                           options={"xatol": 1e-3, "fatol": 1e-9, "maxiter": 200})
            e = float(np.clip(opt.x[0], *CONDUCTOR_ETA_RANGE))
            k = float(np.clip(opt.x[1], *KAPPA_RANGE))
            r, x = chi2(kind, e, k)
            results[kind] = (r, e, k, x)
    n_par = {"none": 0, "dielectric": 1, "conductor": 2}
    n_val = y.size

    def bic(kind: str) -> float:
        r, _, _, x = results[kind]
        k = int(np.sum(x > 0)) + n_par[kind]
        return n_val * math.log(max(r, 1e-300) / n_val) + k * math.log(n_val)

    kind = min(results, key=bic)
    _, eta, kappa, x = results[kind]
    total = float(np.sum(x[1:]))
    if total <= 0:  # no specular part at all: a Lambertian surface
        weights = np.zeros(alphas.size)
        weights[-1] = 1.0
    else:
        weights = x[1:] / total
    model = MicrofacetReconstruction(alphas, weights, kind, eta, kappa, np.zeros(n_c), np.zeros(n_c),
                                     ["value"] if n_c == 1 else ["R", "G", "B"])
    shape = model.specular_shape(wi, wo)
    if near.size:
        shape[near] = (basis[near] @ weights) * fresnel(cd[near], kind, eta, kappa)
    e_spec = _specular_albedo(ENERGY_THETA_I, alphas, weights, kind, eta, kappa)
    cols = np.concatenate([lam, shape[:, None]], axis=1)
    for c in range(n_c):  # the colour, channel by channel, energy-constrained
        model.rho[c], model.ks[c] = _constrained_colour(cols, f[:, c], _weights(f[:, c], std[:, c]), e_spec)
    merged = _merge_below_resolution(model, inst) if near.size else None
    pred = model.eval(wi, wo)
    from reconstruction.core.metrics import relative_rmse_cos_dirs

    model.info = {
        "fit": {"fresnel_candidates": {k: {"chi2": round(v[0], 6), "bic": round(bic(k), 3), "eta": v[1],
                                           "kappa": v[2]} for k, v in results.items()},
                "fresnel_chosen": kind, "criterion": "BIC over the Fresnel families",
                "alpha_min": a_why, "weights": f"1 / sqrt(std^2 + ({_REL:g} f)^2 + ({_FLOOR:g} peak)^2)"},
        "residuals": {"relative_rmse_cos": round(relative_rmse_cos_dirs(pred, f, wi, wo), 6),
                      "n_values": int(f.size)},
        "constraints": {"energy": "rho + ks E(theta_i) <= 1 at theta_i = 0-88 deg (E: the specular directional "
                                  "albedo)", "max_directional_albedo": model.albedo().max(axis=0).round(5).tolist()},
        "holes": "the blind spot and missing samples are covered by the fitted model",
    }
    if near.size:
        model.info["instrument"] = {
            "instrument": inst.to_meta(), "cone_averaged_samples": int(near.size),
            "model": "the dictionary's GGX terms averaged over the detector cone at the samples within "
                     f"{NEAR_CONES:g} cone half angles (or 3 deg) of their mirror direction (the Fresnel factor at "
                     "the cone's centre); point values elsewhere", "below_resolution": merged}
    return model


def _merge_below_resolution(model: MicrofacetReconstruction, inst: Instrument) -> dict[str, Any] | None:
    """Write the mixture's terms narrower than the instrument resolves as one term at its resolution alpha, with
    their summed weight (their energy; in place). The cone reads such terms alike, so the data cannot tell them
    apart; the sharpest one a fit happens to pick would put a peak in the table that nothing measured (MERL chrome
    through a 1 deg cone: alpha 1e-4 and a table 100x off). Returns what was merged, or None."""
    from reconstruction.methods.fit.aperture import resolution_alpha

    a_res = resolution_alpha(inst.aperture_half_angle_deg)
    below = (model.alphas < a_res) & (model.weights > 0)
    if not below.any():
        return None
    w = float(model.weights[below].sum())
    keep = model.alphas >= a_res
    model.alphas = np.r_[a_res, model.alphas[keep]]
    model.weights = np.r_[w, model.weights[keep]]
    return {"resolution_alpha": a_res, "weight": w,
            "note": f"terms with alpha < {a_res:.3g} (below the instrument's angular resolution) written at alpha "
                    f"{a_res:.3g} with their weight (energy {w:.3g} of the specular part)"}
