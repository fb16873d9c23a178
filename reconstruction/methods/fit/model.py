"""The fit's model and its least-squares fit: candidate lobe structures (:class:`LobeSpec`), the fitting problem,
:func:`fit_model` (one structure fitted, energy-constrained) and :class:`FitResult` (parameters with uncertainties).
See :mod:`reconstruction.methods.fit` for the method as a whole.
"""


from __future__ import annotations

import itertools
import math
from collections.abc import Sequence
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.base import ReconstructionError
from reconstruction.core.energy import microfacet_albedo, retro_albedo
from reconstruction.core.geometry import normalize
from reconstruction.core.models import Colour, Lambert, Lobe, Material, Microfacet, Retro
from reconstruction.core.samples import sample_directions
from reconstruction.core.slicedata import Slice
from reconstruction.instrument.response import Instrument, InstrumentError
from reconstruction.methods.fit.aperture import ALPHA_FLOOR, Blur

Array = NDArray[np.float64]

__all__ = ["LobeSpec", "FitResult", "fit_model", "gap_bounds", "f0_of_ior", "ior_of_f0", "model_name"]

ALPHA_MIN, ALPHA_MAX = 0.005, 1.5
F0_MIN, F0_MAX = 0.002, 0.998
IOR_MIN, IOR_MAX = (1 + math.sqrt(F0_MIN)) / (1 - math.sqrt(F0_MIN)), (1 + math.sqrt(F0_MAX)) / (1 - math.sqrt(F0_MAX))
EXP_MIN, EXP_MAX = 0.5, 2000.0
# amplitudes are physical fractions: lambert albedo, microfacet specular and retro amount each lie in (0, 1]
LOG_AMP_MIN, LOG_AMP_MAX = math.log(1e-12), 0.0
#: the largest directional albedo a fit may reach by its tabulated lobe albedos (a margin for their interpolation)
ENERGY_TARGET = 0.995
#: incidences (radians) at which every candidate's directional albedo is held <= 1 during the fit
ENERGY_INCIDENCES = np.radians(np.arange(0.0, 89.0, 4.0))
FLOOR = 1e-4  # of each channel's peak |f|
SELECTION_MAX_VALUES = 2400  # residuals (samples x channels) beyond which candidates are compared on a subset
REFIT_MAX_VALUES = 60_000  # the chosen model is refitted to at most this many residuals (an evenly strided subset)


# --- models ----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LobeSpec:
    """One lobe of a candidate model: ``kind`` lambert | ggx | beckmann | retro; ``fresnel`` for microfacets."""

    kind: str
    fresnel: bool = False

    @property
    def name(self) -> str:
        return self.kind + ("(F)" if self.fresnel else "")

    @property
    def nonlinear(self) -> tuple[str, ...]:
        """Names of the shared (geometry) parameters in the fit's parametrisation."""
        if self.kind in ("ggx", "beckmann"):
            return ("log_alpha", "log_ior_minus_1") if self.fresnel else ("log_alpha",)
        if self.kind == "retro":
            return ("log_exponent",)
        return ()


def model_name(specs: Sequence[LobeSpec]) -> str:
    return "+".join(s.name for s in specs)


def f0_of_ior(ior: float) -> float:
    """Normal-incidence Fresnel reflectance of an interface of relative index ``ior``: ((n - 1) / (n + 1))^2."""
    return ((ior - 1.0) / (ior + 1.0)) ** 2


def ior_of_f0(f0: float) -> float:
    """The relative index whose normal-incidence reflectance is ``f0`` (0 < f0 < 1)."""
    r = math.sqrt(f0)
    return (1.0 + r) / (1.0 - r)


def _f0(p: float) -> float:
    """f0 of the fit parameter log(ior - 1)."""
    return f0_of_ior(1.0 + math.exp(p))


def _lobe(spec: LobeSpec, nl: Sequence[float], colour: Array | None = None) -> Lobe:
    """A models.py lobe for ``spec`` with fit parameters ``nl`` (its nonlinear parameters) and colour."""
    col = Colour(np.ones(1) if colour is None else np.asarray(colour, dtype=np.float64))
    if spec.kind == "lambert":
        return Lambert(colour=col)
    if spec.kind in ("ggx", "beckmann"):
        f0 = _f0(nl[1]) if spec.fresnel else None
        return Microfacet(colour=col, alpha=float(math.exp(nl[0])), f0=f0, distribution=spec.kind)
    if spec.kind == "retro":
        return Retro(colour=col, exponent=float(math.exp(nl[0])))
    raise ReconstructionError(f"unknown lobe kind {spec.kind!r}")


def _column(spec: LobeSpec, nl: Sequence[float], prob: _Problem) -> Array:
    """The lobe's shape for unit amplitude (N,) at the problem's samples, 1/sr (with its Fresnel factor: the
    amplitude is the specular scale, <= 1); with the problem's ``blur`` (an instrument of finite aperture) a
    microfacet lobe is averaged over the cone where that matters (:mod:`.aperture`)."""
    lobe = _lobe(spec, nl)
    if not isinstance(lobe, Microfacet):
        return lobe.shape(prob.wi, prob.wo)
    point = lobe.shape_cosines(*prob.cosines)
    if prob.blur is None:
        return point
    return prob.blur.column(lobe.distribution, lobe.alpha, lobe.f0, point)


def _unit_albedo(spec: LobeSpec, nl: Sequence[float], theta_i: Array) -> Array:
    """Directional albedo (n_theta,) of the lobe with unit amplitude at incidences ``theta_i`` (radians)."""
    if spec.kind == "lambert":
        return np.ones_like(theta_i)
    if spec.kind in ("ggx", "beckmann"):
        return microfacet_albedo(theta_i, math.exp(nl[0]), _f0(nl[1]) if spec.fresnel else None, spec.kind)
    return retro_albedo(theta_i, math.exp(nl[0]))


def _energy_scale(specs: Sequence[LobeSpec], nl: Sequence[Array], amps: Array) -> tuple[Array, Array, Array]:
    """(scale (C,), albedo (n_theta, C) before scaling, unit albedos (L, n_theta)): the factor <= 1 per channel
    that brings the model's largest directional albedo over :data:`ENERGY_INCIDENCES` down to
    :data:`ENERGY_TARGET` (the unit albedos are interpolated from tables, good to about 0.3 %: the margin keeps the
    true albedo <= 1)."""
    e = np.stack([_unit_albedo(s, p, ENERGY_INCIDENCES) for s, p in zip(specs, nl, strict=True)])
    alb = e.T @ amps
    return 1.0 / np.maximum(alb.max(axis=0) / ENERGY_TARGET, 1.0), alb, e


@dataclass
class _Problem:
    """Data of one fit: directions, values, sigmas (all per sample) and bounds."""

    wi: Array
    wo: Array
    f: Array  # (N, C)
    sigma: Array  # (N, C) for the start: relative term from the measured values
    alpha_min: float
    std: Array  # (N, C) the samples' own standard deviations
    relative_sigma: float
    floor: Array  # (1, C)
    exponent_max: float = EXP_MAX  # retro lobes no narrower than the gap around the retro direction
    blur: Blur | None = None  # the instrument's cone averages (None: a point instrument)

    def take(self, mask: NDArray[np.bool_]) -> _Problem:
        """The problem restricted to the samples ``mask`` (N,)."""
        return _Problem(self.wi[mask], self.wo[mask], self.f[mask], self.sigma[mask], self.alpha_min,
                        self.std[mask], self.relative_sigma, self.floor, self.exponent_max,
                        self.blur.take(mask) if self.blur is not None else None)

    def sigma_of(self, pred: Array) -> Array:
        """sigma with the relative term taken from the model's prediction (not from the noisy, maybe outlying,
        measured value, which would down-weight high outliers by itself)."""
        return np.sqrt(np.square(self.std) + np.square(self.relative_sigma * pred) + np.square(self.floor))

    @property
    def n(self) -> int:
        return int(self.f.size)

    @cached_property
    def cosines(self) -> tuple[Array, Array, Array, Array]:
        """(cos theta_h, cos theta_d, cos theta_i, cos theta_o) per sample (N,): once per problem (a fit
        evaluates its lobes at the same samples thousands of times)."""
        h = normalize(self.wi + self.wo)
        return h[..., 2], np.sum(self.wi * h, axis=-1), self.wi[..., 2], self.wo[..., 2]


def _nl_grid(spec: LobeSpec, alpha_min: float, exponent_max: float = EXP_MAX) -> list[tuple[float, ...]]:
    if spec.kind in ("ggx", "beckmann"):
        alphas = np.log(np.geomspace(alpha_min, 1.0, 16))
        if spec.fresnel:
            return [(a, math.log(ior_of_f0(f0) - 1.0)) for a in alphas for f0 in (0.02, 0.08, 0.3)]
        return [(a,) for a in alphas]
    if spec.kind == "retro":
        return [(math.log(e),) for e in (1.0, 3.0, 10.0, 30.0, 100.0) if e <= exponent_max] or [
            (math.log(exponent_max),)]
    return [()]


def _nl_bounds(spec: LobeSpec, alpha_min: float, exponent_max: float = EXP_MAX) -> tuple[list[float], list[float]]:
    lo: list[float] = []
    hi: list[float] = []
    for name in spec.nonlinear:
        if name == "log_alpha":
            lo.append(math.log(alpha_min))
            hi.append(math.log(ALPHA_MAX))
        elif name == "log_ior_minus_1":
            lo.append(math.log(IOR_MIN - 1.0))
            hi.append(math.log(IOR_MAX - 1.0))
        else:
            lo.append(math.log(EXP_MIN))
            hi.append(math.log(max(EXP_MIN * 1.01, min(EXP_MAX, exponent_max))))
    return lo, hi


def _weighted_nnls(cols: Array, f: Array, sigma: Array) -> tuple[Array, float]:
    """Amplitudes (L, C) >= 0 minimising sum(((cols @ a - f) / sigma)^2) per channel, and that chi^2."""
    from scipy.optimize import nnls  # here: importing fit without scipy lets a forked child start before it

    n_l, n_c = cols.shape[1], f.shape[1]
    amps = np.zeros((n_l, n_c))
    chi2 = 0.0
    for c in range(n_c):  # 1 or 3 channels
        a, rnorm = nnls(cols / sigma[:, c:c + 1], f[:, c] / sigma[:, c], maxiter=50 * n_l)
        amps[:, c] = a
        chi2 += rnorm * rnorm
    return amps, chi2


def _start(specs: Sequence[LobeSpec], prob: _Problem) -> tuple[list[tuple[float, ...]], Array]:
    """Best grid point of the geometry parameters with NNLS amplitudes (variable projection)."""
    per_lobe = []
    for spec in specs:  # each lobe's columns over its own grid (the product only combines them)
        grid = _nl_grid(spec, prob.alpha_min, prob.exponent_max)
        per_lobe.append([(g, _column(spec, g, prob)) for g in grid])
    best: tuple[float, list[tuple[float, ...]], Array] | None = None
    for combo in itertools.product(*per_lobe):
        cols = np.stack([c for _, c in combo], axis=1)
        amps, chi2 = _weighted_nnls(cols, prob.f, prob.sigma)
        if best is None or chi2 < best[0]:
            best = (chi2, [g for g, _ in combo], amps)
    assert best is not None
    return best[1], best[2]


@dataclass
class FitResult:
    """One fitted candidate model."""

    specs: tuple[LobeSpec, ...]
    x: Array
    n_nonlinear: int
    n_channels: int
    cost: float  # 0.5 * robust chi^2
    chi2: float  # plain chi^2 of the normalised residuals
    n: int  # residuals (samples x channels)
    jac: Array
    residuals: Array  # (N, C) normalised residuals (f_model - f) / sigma
    success: bool
    message: str
    nfev: int

    @property
    def name(self) -> str:
        return model_name(self.specs)

    @property
    def k(self) -> int:
        return int(self.x.size)

    @property
    def bic(self) -> float:
        return 2.0 * self.cost + self.k * math.log(self.n)

    def split(self, x: Array | None = None) -> tuple[list[Array], Array]:
        """(nonlinear parameters per lobe, log amplitudes (L, C)) of ``x`` (default: the solution)."""
        x = self.x if x is None else x
        nl, k = [], 0
        for s in self.specs:
            m = len(s.nonlinear)
            nl.append(x[k:k + m])
            k += m
        return nl, x[self.n_nonlinear:].reshape(len(self.specs), self.n_channels)

    def amplitudes(self, x: Array | None = None) -> Array:
        """The amplitudes (L, C) of ``x`` as the model uses them: held to a directional albedo <= 1."""
        nl, la = self.split(x)
        amps = np.exp(la)
        return amps * _energy_scale(self.specs, nl, amps)[0][None, :]

    def natural(self, x: Array | None = None) -> Array:
        """The reported parameters as one vector (see :meth:`parameter_names`)."""
        nl, _ = self.split(x)
        out: list[float] = []
        for spec, p, amp in zip(self.specs, nl, self.amplitudes(x), strict=True):
            if spec.kind in ("ggx", "beckmann"):
                out.append(math.exp(p[0]))
                if spec.fresnel:
                    out.append(1.0 + math.exp(p[1]))
                    out.append(_f0(p[1]))
            elif spec.kind == "retro":
                out.append(math.exp(p[0]))
            out.extend(amp.tolist())
        return np.array(out)

    def parameter_names(self) -> list[tuple[int, str, int | None]]:
        """(lobe index, key, channel or None) for each entry of :meth:`natural`."""
        names: list[tuple[int, str, int | None]] = []
        for i, spec in enumerate(self.specs):
            if spec.kind in ("ggx", "beckmann"):
                names.append((i, "alpha", None))
                if spec.fresnel:
                    names.append((i, "ior", None))
                    names.append((i, "f0", None))
                key = "specular"
            elif spec.kind == "retro":
                names.append((i, "exponent", None))
                key = "amount"
            else:
                key = "albedo"
            names.extend((i, key, c) for c in range(self.n_channels))
        return names

    def material(self, name: str = "fit") -> Material:
        nl, _ = self.split()
        lobes = [_lobe(spec, p, amp) for spec, p, amp in zip(self.specs, nl, self.amplitudes(), strict=True)]
        return Material(name, lobes)

    def albedo(self) -> Array:
        """Directional albedo (n_theta, C) of the fitted model at :data:`ENERGY_INCIDENCES` (from the lobes'
        tabulated unit albedos)."""
        nl, _ = self.split()
        e = np.stack([_unit_albedo(s, p, ENERGY_INCIDENCES) for s, p in zip(self.specs, nl, strict=True)])
        return e.T @ self.amplitudes()

    def covariance(self) -> Array:
        """Covariance of the fit parameters x: pinv(J^T J) * max(1, reduced chi^2); inf where not determined."""
        j = self.jac
        _, s, vt = np.linalg.svd(j, full_matrices=False)
        tol = s[0] * 1e-10 if s.size else 0.0
        keep = (s > tol) & (s > 1e-150)  # 1 / s^2 stays finite
        inv = np.divide(1.0, s * s, out=np.zeros_like(s), where=keep)
        cov = (vt.T * inv) @ vt
        dof = max(self.n - self.k, 1)
        cov *= max(1.0, 2.0 * self.cost / dof)
        undetermined = np.abs(vt[s <= tol]).max(axis=0) > 1e-6 if np.any(s <= tol) else np.zeros(self.k, bool)
        d = np.diag(cov).copy()
        d[undetermined] = np.inf
        np.fill_diagonal(cov, d)
        return cov

    def uncertainties(self) -> Array:
        """Standard deviations of :meth:`natural`, by the delta method (central differences of the mapping)."""
        cov = self.covariance()
        base = self.natural()
        jg = np.empty((base.size, self.k))
        for k in range(self.k):  # k ~ 10 parameters
            h = 1e-6 * max(1.0, abs(self.x[k]))
            xp, xm = self.x.copy(), self.x.copy()
            xp[k] += h
            xm[k] -= h
            jg[:, k] = (self.natural(xp) - self.natural(xm)) / (2 * h)
        finite = np.isfinite(np.diag(cov))
        var = np.einsum("ik,kl,il->i", jg[:, finite], cov[np.ix_(finite, finite)], jg[:, finite])
        var[np.any(np.abs(jg[:, ~finite]) > 1e-12, axis=1)] = np.inf
        return np.sqrt(np.maximum(var, 0.0))

    def parameters(self) -> list[dict[str, Any]]:
        """Reported parameters per lobe with ``<key>_std`` uncertainties (JSON-ready; inf -> None)."""
        vals, stds = self.natural(), self.uncertainties()
        lobes: list[dict[str, Any]] = [{"type": s.kind} for s in self.specs]
        for (i, key, c), v, sd in zip(self.parameter_names(), vals, stds, strict=True):
            sdv = float(sd) if np.isfinite(sd) else None
            if c is None:
                lobes[i][key] = float(v)
                lobes[i][key + "_std"] = sdv
            else:
                lobes[i].setdefault(key, []).append(float(v))
                lobes[i].setdefault(key + "_std", []).append(sdv)
        return lobes

    def summary(self) -> dict[str, Any]:
        return {"model": self.name, "k": self.k, "bic": round(self.bic, 4), "robust_chi2": round(2 * self.cost, 4),
                "chi2": round(self.chi2, 4), "converged": self.success}


#: GGX half width at half maximum in theta_h: tan(theta) = HWHM_PER_ALPHA alpha (sqrt(sqrt(2) - 1))
HWHM_PER_ALPHA = math.sqrt(math.sqrt(2.0) - 1.0)


def _nearest_gap(offsets: Array) -> float:
    """Half the width of the sample gap around offset 0 (degrees): the larger distance to the nearest sample on
    either side; 0 when a sample lies within 0.25 deg of it."""
    if offsets.size == 0 or np.min(np.abs(offsets)) <= 0.25:
        return 0.0
    below, above = offsets[offsets < 0], offsets[offsets > 0]
    sides = [float(-below.max())] if below.size else []
    sides += [float(above.min())] if above.size else []
    return max(sides)


def gap_bounds(s: Slice) -> dict[str, float]:
    """Bounds that keep lobes where the samples constrain them (degrees of theta_o in, dimensionless out).

    A specular lobe whose mirror direction falls in a sampling gap of every incidence could hide a narrow peak
    there: ``alpha_min`` makes its half width at half maximum (tan theta_h = 0.64 alpha) at least half the gap
    in theta_h at the best-sampled incidence. A retro lobe peaks at theta_o = -theta_i, always inside the blind
    spot: ``exponent_max`` keeps its value at the nearest sample at least half its peak (cos^n(gap) >= 0.5),
    so the samples around the gap bound its amplitude.
    """
    mirror, retro = [], []
    for t in s.incidences():  # a handful of incidences
        to = s.theta_o_deg[s.theta_i_deg == t]
        mirror.append(_nearest_gap(to - t))
        retro.append(_nearest_gap(to + t))
    m_gap = min(mirror) if mirror else 0.0
    r_gap = min(retro) if retro else 0.0
    alpha_min = math.tan(math.radians(m_gap) / 2.0) / HWHM_PER_ALPHA if m_gap > 0 else 0.0
    exponent_max = math.log(0.5) / math.log(math.cos(math.radians(r_gap))) if r_gap > 0 else EXP_MAX
    return {"mirror_gap_deg": m_gap, "retro_gap_deg": r_gap, "alpha_min": alpha_min,
            "retro_exponent_max": min(EXP_MAX, exponent_max)}


def _problem(s: Slice, relative_sigma: float, alpha_min: float) -> _Problem:
    f, std = s.brdf()
    assert std is not None
    floor = FLOOR * np.maximum(np.max(np.abs(f), axis=0, keepdims=True), 1e-300)
    sigma = np.sqrt(np.square(std) + np.square(relative_sigma * f) + np.square(floor))
    wi, wo = sample_directions(s)  # in-plane, or anywhere for a DirectionalSlice (reconstruction.core.samples)
    try:
        inst = Instrument.from_meta(s.meta.get("instrument"))
    except InstrumentError as e:
        raise ReconstructionError(f"{s.source}: metadata {e}") from None
    # a finite aperture: microfacet columns are cone averages, and a lobe may be narrower than ALPHA_MIN
    blur = None if inst.detector_solid_angle_sr == 0.0 and inst.source_divergence_deg == 0.0 else Blur(inst, wi, wo)
    alpha_min = max(alpha_min, ALPHA_MIN if blur is None else ALPHA_FLOOR)
    return _Problem(wi, wo, f, sigma, alpha_min, std, relative_sigma, floor, blur=blur)


def fit_model(specs: Sequence[LobeSpec], prob: _Problem, *, loss: str = "soft_l1", f_scale: float = 2.0,
              max_nfev: int = 400) -> FitResult:
    """Fit one candidate model (sum of ``specs`` lobes) to the problem's samples."""
    from scipy.optimize import least_squares

    specs = tuple(specs)
    n_c = prob.f.shape[1]
    nl0, amps0 = _start(specs, prob)
    lo: list[float] = []
    hi: list[float] = []
    for spec in specs:
        a, b = _nl_bounds(spec, prob.alpha_min, prob.exponent_max)
        lo += a
        hi += b
    n_nl = len(lo)
    peak = np.maximum(np.max(np.abs(prob.f), axis=0), 1e-300)
    amp_floor = np.maximum(1e-6 * peak, math.exp(LOG_AMP_MIN) * 10)
    la0 = np.log(np.maximum(amps0, amp_floor[None, :]))
    lo += [LOG_AMP_MIN] * la0.size
    hi += [LOG_AMP_MAX] * la0.size
    lo_a, hi_a = np.array(lo), np.array(hi)
    x0 = np.concatenate([np.concatenate([np.asarray(g, dtype=np.float64) for g in nl0]) if n_nl else np.empty(0),
                         la0.ravel()])
    inner = (lo_a + 1e-9 * (hi_a - lo_a), hi_a - 1e-9 * (hi_a - lo_a))  # least_squares starts strictly inside
    x0 = np.clip(x0, *inner)

    lobe_of = [li for li, spec in enumerate(specs) for _ in spec.nonlinear]  # the lobe of each geometry parameter

    def unpack(x: Array) -> tuple[list[Array], Array]:
        nl, k = [], 0
        for s in specs:
            m = len(s.nonlinear)
            nl.append(x[k:k + m])
            k += m
        return nl, np.exp(x[n_nl:].reshape(len(specs), n_c))

    def columns(nl: list[Array]) -> Array:
        return np.stack([_column(s, p, prob) for s, p in zip(specs, nl, strict=True)], axis=1)

    sigma = prob.sigma

    # The model is energy-conserving by construction: the amplitudes of each channel are scaled by
    # s_c = 1 / max(1, max_theta albedo_c(theta)), so no candidate ever reflects more than it receives.
    def predict(nl: list[Array], amps: Array) -> tuple[Array, Array, Array, Array, Array]:
        cols = columns(nl)
        scale, alb, e = _energy_scale(specs, nl, amps)
        return cols @ (amps * scale[None, :]), cols, scale, alb, e

    last: dict[bytes, tuple[Array, Array, Array, Array, Array]] = {}

    def predict_at(x: Array) -> tuple[Array, Array, Array, Array, Array]:
        # least_squares asks for fun and then jac at the same x: the model is evaluated once for both
        key = x.tobytes()
        if key not in last:
            last.clear()
            last[key] = predict(*unpack(x))
        return last[key]

    def fun(x: Array) -> Array:
        return ((predict_at(x)[0] - prob.f) / sigma).ravel()

    def jac(x: Array) -> Array:
        # amplitudes analytically (through the energy scale); geometry by forward differences
        nl, amps = unpack(x)
        pred, cols, scale, alb, e = predict_at(x)
        base = ((pred - prob.f) / sigma).ravel()
        j = np.zeros((base.size, x.size))
        for k in range(n_nl):  # a few geometry parameters: only lobe li's column and the energy scale move
            h = 1e-7 * max(1.0, abs(x[k]))
            xk = x.copy()
            xk[k] = min(x[k] + h, hi_a[k]) if x[k] + h <= hi_a[k] else x[k] - h
            li = lobe_of[k]
            nl_k, _ = unpack(xk)
            cols_k = cols.copy()
            cols_k[:, li] = _column(specs[li], nl_k[li], prob)
            pred_k = cols_k @ (amps * _energy_scale(specs, nl_k, amps)[0][None, :])
            j[:, k] = (((pred_k - prob.f) / sigma).ravel() - base) / (xk[k] - x[k])
        n_s = prob.f.shape[0]
        unscaled = cols @ amps  # (N, C)
        top = np.argmax(alb, axis=0)  # the incidence of each channel's largest albedo
        active = alb.max(axis=0) > 1.0
        rows = np.arange(n_s)[:, None] * n_c + np.arange(n_c)[None, :]
        for li in range(len(specs)):
            # d pred[s, c] / d log a[li, c] = s_c cols[s, li] a[li, c] + unscaled[s, c] d s_c / d log a[li, c]
            ds = np.where(active, -scale ** 2 * e[li, top] * amps[li], 0.0)
            blk = (cols[:, li:li + 1] * (amps[li] * scale)[None, :] + unscaled * ds[None, :]) / sigma
            idx = n_nl + li * n_c + np.arange(n_c)
            j[rows, np.broadcast_to(idx, (n_s, n_c))] = blk
        return j

    kw: dict[str, Any] = {"jac": jac, "bounds": (lo_a, hi_a), "loss": loss, "f_scale": f_scale, "x_scale": "jac",
                          "method": "trf", "max_nfev": max_nfev}
    res = least_squares(fun, x0, **kw)
    # second pass: the relative uncertainty of each sample from the model's value there, warm-started
    sigma = prob.sigma_of(predict_at(res.x)[0])
    nfev = res.nfev
    res = least_squares(fun, np.clip(res.x, *inner), **kw)
    r = res.fun.reshape(prob.f.shape)
    return FitResult(specs, res.x, n_nl, n_c, float(res.cost), float(np.sum(r * r)), prob.n, res.jac, r,
                     bool(res.success), str(res.message), int(nfev + res.nfev))
