"""The ``fit`` method: analytic lobes fitted to in-plane slices, the number and kind of lobes chosen by BIC.

Model: a sum of lobes from :mod:`reconstruction.models` (so the result is a :class:`~reconstruction.models.Material`):
``lambert`` (albedo), ``ggx`` / ``beckmann`` (alpha, specular, optional Schlick Fresnel f0) and ``retro``
(exponent, amount). Geometry parameters (alpha, f0, exponent) are shared by all channels; every lobe has one
amplitude per channel.

Fit (scipy.optimize.least_squares, method "trf"):

* parametrisation: log alpha, logit f0, log exponent, log amplitudes. With Fresnel, the amplitude is the
  normal-incidence reflectance specular * f0 (well determined) and the report gives specular = amplitude / f0;
* residuals (f_model - f) / sigma with sigma = sqrt(std^2 + (relative_sigma f_model)^2 + floor^2): ``std`` from
  the samples, a relative term for calibration and model error (1 % by default) and a floor of 1e-4 of the
  channel's peak that keeps weights finite for noise-free data. The relative term is taken from the model's value
  (a first pass uses the measured value, a warm-started second pass the model's), so an outlying sample does not
  widen its own error bar;
* robust loss ``soft_l1`` with ``f_scale`` = 2 sigma (outliers beyond ~2 sigma weigh linearly, not quadratically);
* start: a grid over the geometry parameters with non-negative linear least squares for the amplitudes
  (variable projection), then the joint non-linear refinement;
* uncertainties: covariance (J^T J)^-1 * max(1, reduced chi^2) from the Jacobian at the solution, carried to the
  reported parameters (alpha, f0, albedo, specular, ...) by the delta method.

Model selection: candidates are fitted stepwise (lambert, ggx, beckmann, lambert + ggx, lambert + beckmann; then the
best of these for each distribution with Fresnel, with a retro lobe, with both, and with a lambert lobe added) and
the one with the lowest BIC = robust chi^2 + k ln(n) is kept, so a lobe stays only when the data require it.

Scene files (``--scene configs/scenes/NAME.toml``, :mod:`reconstruction.scene`) say what the reconstruction is
for: the lobe kinds allowed, the angular resolution (lobes narrower than it are not resolved: alpha >=
radians(resolution) / 2.6), the relative_sigma used in the weights and an error budget (relative_rmse: the simplest
candidate within it of the BIC choice over the scene's directions is used). A range the scene file does not give
is taken as 0-85 deg here (:data:`SCENE_DEFAULT_RANGE_DEG`).
"""

from __future__ import annotations

import itertools
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares, nnls
from threadpoolctl import threadpool_limits

from .base import ReconstructionError
from .energy import microfacet_albedo, retro_albedo
from .geometry import sph_to_vec
from .metrics import relative_rmse_cos_dirs
from .models import Colour, Lambert, Lobe, Material, Microfacet, Retro
from .samples import sample_directions
from .scene import LOBE_KINDS, Scene
from .slicefile import Slice

Array = NDArray[np.float64]

__all__ = ["LobeSpec", "FitResult", "FitReconstruction", "fit_model", "reconstruct_fit", "scene_alpha_min",
           "scene_directions", "LOBE_KINDS", "SCENE_DEFAULT_RANGE_DEG"]

ALPHA_MIN, ALPHA_MAX = 0.005, 1.5
F0_MIN, F0_MAX = 0.002, 0.998
IOR_MIN, IOR_MAX = (1 + math.sqrt(F0_MIN)) / (1 - math.sqrt(F0_MIN)), (1 + math.sqrt(F0_MAX)) / (1 - math.sqrt(F0_MAX))
EXP_MIN, EXP_MAX = 0.5, 2000.0
# amplitudes are physical fractions: lambert albedo, microfacet specular and retro amount each lie in (0, 1]
LOG_AMP_MIN, LOG_AMP_MAX = math.log(1e-12), 0.0
#: incidences (radians) at which every candidate's directional albedo is held <= 1 during the fit
ENERGY_INCIDENCES = np.radians(np.arange(0.0, 89.0, 4.0))
FLOOR = 1e-4  # of each channel's peak |f|
SELECTION_MAX_VALUES = 2400  # residuals (samples x channels) beyond which candidates are compared on a subset


# --- scenes ----------------------------------------------------------------------------------------------

#: theta_i and theta_o range (degrees) of a scene whose file gives none (the capture's default differs: it is the
#: whole hemisphere, see acquisition.plan).
SCENE_DEFAULT_RANGE_DEG = (0.0, 85.0)


def scene_alpha_min(scene: Scene | None) -> float:
    """Smallest microfacet alpha worth resolving in ``scene`` (dimensionless)."""
    if scene is None or scene.angular_resolution_deg is None:
        return ALPHA_MIN
    return max(ALPHA_MIN, math.radians(scene.angular_resolution_deg) / 2.6)


def scene_directions(scene: Scene, max_pairs: int = 200_000) -> tuple[Array, Array]:
    """Direction pairs (M, 3) spanning ``scene``: theta_i, theta_o in its ranges, relative azimuth 0-180 deg."""
    (ti_lo, ti_hi), (to_lo, to_hi) = scene.ranges(SCENE_DEFAULT_RANGE_DEG)
    step = max(1.0, scene.angular_resolution_deg or 2.0)
    while True:
        ti = np.radians(np.arange(ti_lo, ti_hi + 1e-9, step))
        to = np.radians(np.arange(to_lo, to_hi + 1e-9, step))
        ph = np.radians(np.arange(0.0, 180.0 + 1e-9, step))
        if ti.size * to.size * ph.size <= max_pairs:
            break
        step *= 1.5
    a, b, p = np.meshgrid(ti, to, ph, indexing="ij")
    wi = sph_to_vec(a.ravel(), np.pi)
    wo = sph_to_vec(b.ravel(), np.pi + p.ravel())
    return wi, wo


def _scene_report(scene: Scene) -> dict[str, Any]:
    ti, to = scene.ranges(SCENE_DEFAULT_RANGE_DEG)
    return {"name": scene.name, "source": scene.source, "theta_i_deg": list(ti), "theta_o_deg": list(to),
            "angular_resolution_deg": scene.angular_resolution_deg,
            "lobes": list(scene.lobes) if scene.lobes else None, "relative_rmse": scene.relative_rmse,
            "relative_sigma": scene.relative_sigma}


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


def _column(spec: LobeSpec, nl: Sequence[float], wi: Array, wo: Array) -> Array:
    """The lobe's shape for unit amplitude (N,), 1/sr (with its Fresnel factor: the amplitude is the specular
    scale, <= 1)."""
    return _lobe(spec, nl).shape(wi, wo)


def _unit_albedo(spec: LobeSpec, nl: Sequence[float], theta_i: Array) -> Array:
    """Directional albedo (n_theta,) of the lobe with unit amplitude at incidences ``theta_i`` (radians)."""
    if spec.kind == "lambert":
        return np.ones_like(theta_i)
    if spec.kind in ("ggx", "beckmann"):
        return microfacet_albedo(theta_i, math.exp(nl[0]), _f0(nl[1]) if spec.fresnel else None, spec.kind)
    return retro_albedo(theta_i, math.exp(nl[0]))


def _energy_scale(specs: Sequence[LobeSpec], nl: Sequence[Array], amps: Array) -> tuple[Array, Array, Array]:
    """(scale (C,), albedo (n_theta, C) before scaling, unit albedos (L, n_theta)): the factor <= 1 per channel
    that brings the model's largest directional albedo over :data:`ENERGY_INCIDENCES` down to 1."""
    e = np.stack([_unit_albedo(s, p, ENERGY_INCIDENCES) for s, p in zip(specs, nl, strict=True)])
    alb = e.T @ amps
    return 1.0 / np.maximum(alb.max(axis=0), 1.0), alb, e


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

    def take(self, mask: NDArray[np.bool_]) -> _Problem:
        """The problem restricted to the samples ``mask`` (N,)."""
        return _Problem(self.wi[mask], self.wo[mask], self.f[mask], self.sigma[mask], self.alpha_min,
                        self.std[mask], self.relative_sigma, self.floor, self.exponent_max)

    def sigma_of(self, pred: Array) -> Array:
        """sigma with the relative term taken from the model's prediction (not from the noisy, maybe outlying,
        measured value, which would down-weight high outliers by itself)."""
        return np.sqrt(np.square(self.std) + np.square(self.relative_sigma * pred) + np.square(self.floor))

    @property
    def n(self) -> int:
        return int(self.f.size)


def _nl_grid(spec: LobeSpec, alpha_min: float, exponent_max: float = EXP_MAX) -> list[tuple[float, ...]]:
    if spec.kind in ("ggx", "beckmann"):
        alphas = np.log(np.geomspace(max(alpha_min, ALPHA_MIN), 1.0, 16))
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
            lo.append(math.log(max(alpha_min, ALPHA_MIN)))
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
        per_lobe.append([(g, _column(spec, g, prob.wi, prob.wo)) for g in grid])
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
        inv = np.where(s > tol, 1.0 / np.maximum(s, 1e-300) ** 2, 0.0)
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
    wi, wo = sample_directions(s)  # in-plane, or anywhere for a DirectionalSlice (reconstruction.samples)
    return _Problem(wi, wo, f, sigma, alpha_min, std, relative_sigma, floor)


def fit_model(specs: Sequence[LobeSpec], prob: _Problem, *, loss: str = "soft_l1", f_scale: float = 2.0,
              max_nfev: int = 400) -> FitResult:
    """Fit one candidate model (sum of ``specs`` lobes) to the problem's samples."""
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

    def unpack(x: Array) -> tuple[list[Array], Array]:
        nl, k = [], 0
        for s in specs:
            m = len(s.nonlinear)
            nl.append(x[k:k + m])
            k += m
        return nl, np.exp(x[n_nl:].reshape(len(specs), n_c))

    def columns(nl: list[Array]) -> Array:
        return np.stack([_column(s, p, prob.wi, prob.wo) for s, p in zip(specs, nl, strict=True)], axis=1)

    sigma = prob.sigma

    # The model is energy-conserving by construction: the amplitudes of each channel are scaled by
    # s_c = 1 / max(1, max_theta albedo_c(theta)), so no candidate ever reflects more than it receives.
    def predict(nl: list[Array], amps: Array) -> tuple[Array, Array, Array, Array, Array]:
        cols = columns(nl)
        scale, alb, e = _energy_scale(specs, nl, amps)
        return cols @ (amps * scale[None, :]), cols, scale, alb, e

    def fun(x: Array) -> Array:
        nl, amps = unpack(x)
        return ((predict(nl, amps)[0] - prob.f) / sigma).ravel()

    def jac(x: Array) -> Array:
        # amplitudes analytically (through the energy scale); geometry by forward differences
        nl, amps = unpack(x)
        pred, cols, scale, alb, e = predict(nl, amps)
        base = ((pred - prob.f) / sigma).ravel()
        j = np.zeros((base.size, x.size))
        for k in range(n_nl):  # a few geometry parameters
            h = 1e-7 * max(1.0, abs(x[k]))
            xk = x.copy()
            xk[k] = min(x[k] + h, hi_a[k]) if x[k] + h <= hi_a[k] else x[k] - h
            j[:, k] = (fun(xk) - base) / (xk[k] - x[k])
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
    nl, amps = unpack(res.x)
    sigma = prob.sigma_of(predict(nl, amps)[0])
    nfev = res.nfev
    res = least_squares(fun, np.clip(res.x, *inner), **kw)
    r = res.fun.reshape(prob.f.shape)
    return FitResult(specs, res.x, n_nl, n_c, float(res.cost), float(np.sum(r * r)), prob.n, res.jac, r,
                     bool(res.success), str(res.message), int(nfev + res.nfev))


# --- the reconstruction ----------------------------------------------------------------------------------


@dataclass
class FitReconstruction:
    """Result of :func:`reconstruct_fit`: a fitted :class:`Material` and the fit's report."""

    material: Material
    channels: list[str]
    result: FitResult
    info: dict[str, Any] = field(default_factory=dict)
    method: str = "fit"

    def eval(self, wi: Array, wo: Array) -> Array:
        """f_r (N, C) in 1/sr at unit direction pairs (N, 3); 0 below the horizon."""
        return self.material.eval(wi, wo)

    def report(self) -> dict[str, Any]:
        return {"method": self.method, "model": self.result.name, "material": self.material.to_dict(),
                "parameters": self.result.parameters(), **self.info}


def _candidates_stage1(allowed: set[str]) -> list[tuple[LobeSpec, ...]]:
    out: list[tuple[LobeSpec, ...]] = []
    if "lambert" in allowed:
        out.append((LobeSpec("lambert"),))
    for d in ("ggx", "beckmann"):
        if d in allowed:
            out.append((LobeSpec(d),))
            if "lambert" in allowed:
                out.append((LobeSpec("lambert"), LobeSpec(d)))
    return out


def _extensions(best: tuple[LobeSpec, ...], allowed: set[str]) -> list[tuple[LobeSpec, ...]]:
    """Richer variants of ``best``: Fresnel on its microfacet lobe, a retro lobe, both, a lambert lobe."""
    out: list[tuple[LobeSpec, ...]] = []
    has_mf = any(s.kind in ("ggx", "beckmann") for s in best)
    with_f = tuple(LobeSpec(s.kind, True) if s.kind in ("ggx", "beckmann") else s for s in best)
    if has_mf and "fresnel" in allowed:
        out.append(with_f)
    if "retro" in allowed:
        out.append(best + (LobeSpec("retro"),))
        if has_mf and "fresnel" in allowed:
            out.append(with_f + (LobeSpec("retro"),))
    if "lambert" in allowed and not any(s.kind == "lambert" for s in best):
        out.append((LobeSpec("lambert"),) + best)
    return out


@threadpool_limits.wrap(limits=1, user_api="blas")  # tiny matrices: BLAS threads only cost time
def reconstruct_fit(
    slices: Slice,
    *,
    scene: Scene | None = None,
    lobes: Sequence[str] | None = None,
    loss: str = "soft_l1",
    f_scale: float = 2.0,
    relative_sigma: float | None = None,
    progress: Callable[[str], None] | None = None,
    specs: Sequence[LobeSpec] | None = None,
) -> FitReconstruction:
    """Fit analytic lobes to ``slices`` (f_r, 1 or 3 channels) and choose the model by BIC (and the scene).

    ``specs``: fit this model structure only (no search), e.g. to refit a chosen model to a subset of samples.

    ``lobes``: the lobe kinds allowed (subset of :data:`LOBE_KINDS`; default all, or the scene's list).
    ``relative_sigma``: relative uncertainty added to the samples' std (default the scene's, else 0.01).
    ``progress`` is called with each candidate's name before it is fitted.
    """
    if slices.quantity != "brdf":
        f_, std_ = slices.brdf()
        slices = Slice(slices.theta_i_deg, slices.theta_o_deg, f_, list(slices.channels), std_, slices.repeats,
                       slices.unix_time_s, meta={"quantity": "brdf"}, source=slices.source)
    n_c = len(slices.channels)
    if slices.kind == "spectral" or n_c not in (1, 3):
        raise ReconstructionError(f"{slices.source}: fit works on 1 (grey) or 3 (RGB) channels, got {n_c}; "
                                  f"convert spectra with reconstruction.colour first")
    if len(slices) < 3:
        raise ReconstructionError(f"{slices.source}: {len(slices)} sample(s); fit needs at least 3")
    allowed = set(lobes if lobes is not None else (scene.lobes if scene and scene.lobes else LOBE_KINDS))
    unknown = allowed - set(LOBE_KINDS)
    if unknown:
        raise ReconstructionError(f"unknown lobe kind(s) {sorted(unknown)}; expected {', '.join(LOBE_KINDS)}")
    if not allowed & {"lambert", "ggx", "beckmann"}:
        raise ReconstructionError("fit needs at least one of the lobes lambert, ggx, beckmann")
    rel = relative_sigma if relative_sigma is not None else (scene.relative_sigma if scene and scene.relative_sigma
                                                             else 0.01)
    gaps = gap_bounds(slices)
    full = _problem(slices, rel, max(scene_alpha_min(scene), gaps["alpha_min"]))
    full.exponent_max = gaps["retro_exponent_max"]
    wi, wo, f = full.wi, full.wo, full.f
    # many samples: candidates are compared on an evenly strided subset (every stride-th sample in
    # (theta_i, theta_o) order), then the chosen model is refitted to all samples
    stride = max(1, math.ceil(full.n / SELECTION_MAX_VALUES))
    order = np.lexsort((slices.theta_o_deg, slices.theta_i_deg))
    pick = np.zeros(len(slices), dtype=bool)
    pick[order[::stride]] = True
    prob = full.take(pick) if stride > 1 else full

    fitted: dict[str, FitResult] = {}
    skipped: list[str] = []

    def run(specs: tuple[LobeSpec, ...]) -> None:
        name = model_name(specs)
        if name in fitted:
            return
        k = sum(len(s.nonlinear) for s in specs) + len(specs) * n_c
        if k >= prob.n:
            skipped.append(f"{name}: {k} parameters for {prob.n} values")
            return
        if progress:
            progress(name)
        fitted[name] = fit_model(specs, prob, loss=loss, f_scale=f_scale)

    fixed = tuple(specs) if specs is not None else None
    for cand in [fixed] if fixed else _candidates_stage1(allowed):
        run(cand)
    if not fitted:
        raise ReconstructionError(f"{slices.source}: too few samples ({len(slices)}) for any candidate model")
    # stage 2: the best stage-1 model of each distribution (and the best overall), made richer
    bases = [] if fixed else [min(fitted.values(), key=lambda r: r.bic)]
    for d in ("ggx", "beckmann") if not fixed else ():
        of_d = [r for r in fitted.values() if any(s.kind == d for s in r.specs)]
        if of_d:
            bases.append(min(of_d, key=lambda r: r.bic))
    for base in bases:
        for cand in _extensions(base.specs, allowed):
            run(cand)
    ranked = sorted(fitted.values(), key=lambda r: r.bic)
    chosen = ranked[0]
    why = (f"lowest BIC ({chosen.bic:.1f}) of {len(ranked)} candidates; the next, {ranked[1].name}, has "
           f"{ranked[1].bic:.1f}" if len(ranked) > 1 else "the only candidate")
    scene_info: dict[str, Any] | None = None
    fit_mask: NDArray[np.bool_] | None = None  # the samples the chosen model is fitted to, if not all
    if scene is not None and not fixed:
        scene_info = {"scene": _scene_report(scene)}
        (ti_lo, ti_hi), (to_lo, to_hi) = scene.ranges(SCENE_DEFAULT_RANGE_DEG)
        if scene.relative_rmse is not None:
            # simpler candidates, refitted to the samples inside the scene's ranges (the rest does not matter to
            # the scene), are compared with the BIC choice over the scene's directions; the simplest within the
            # budget is used
            ti_d, to_d = slices.theta_i_deg, np.abs(slices.theta_o_deg)
            inside = ((ti_d >= ti_lo - 1e-9) & (ti_d <= ti_hi + 1e-9)
                      & (to_d >= to_lo - 1e-9) & (to_d <= to_hi + 1e-9))
            in_prob = inside[pick] if stride > 1 else inside
            sub = prob.take(in_prob) if 0 < in_prob.sum() < prob.f.shape[0] else prob
            swi, swo = scene_directions(scene)
            ref = chosen.material().eval(swi, swo)
            diffs = []
            for k in sorted({r.k for r in fitted.values() if r.k < min(chosen.k, sub.n)}):  # simplest first
                best: tuple[float, FitResult] | None = None
                for r in (r for r in fitted.values() if r.k == k):
                    rr = fit_model(r.specs, sub, loss=loss, f_scale=f_scale) if sub is not prob else r
                    e = relative_rmse_cos_dirs(rr.material().eval(swi, swo), ref, swi, swo)
                    diffs.append({"model": r.name, "k": k, "relative_rmse_vs_bic_choice": round(e, 5)})
                    if e <= scene.relative_rmse and (best is None or e < best[0]):
                        best = (e, rr)
                if best is not None:
                    why = (f"simplest candidate within the scene's error budget: {best[1].name}, fitted to the "
                           f"{sub.f.shape[0]} samples inside the scene's ranges, differs from the BIC choice "
                           f"{chosen.name} by {best[0]:.4f} relative RMSE of f cos cos over the scene's directions "
                           f"(budget {scene.relative_rmse})")
                    chosen = best[1]
                    if sub is not prob:
                        fit_mask = inside
                    break
            scene_info["budget_comparison"] = diffs
            scene_info["samples_inside_scene"] = int(sub.f.shape[0])
        lo_i, hi_i = float(np.min(slices.theta_i_deg)), float(np.max(slices.theta_i_deg))
        if ti_hi > hi_i + 1e-9 or ti_lo < lo_i - 1e-9:
            scene_info["warning"] = (f"the scene uses theta_i {ti_lo:g}-{ti_hi:g} deg "
                                     f"but the data cover {lo_i:g}-{hi_i:g} deg; outside that the fit extrapolates")

    notes: list[str] = []
    if stride > 1:
        target = full.take(fit_mask) if fit_mask is not None else full
        chosen = fit_model(chosen.specs, target, loss=loss, f_scale=f_scale)
        notes.append(f"candidates compared on 1 in {stride} of the {len(slices)} samples; {chosen.name} refitted "
                     f"to {target.f.shape[0]} samples")
    material = chosen.material(name=f"fit {chosen.name}")
    model = material.eval(wi, wo)
    resid = (model - f) / full.sigma_of(model)  # every sample, whatever subset the model was fitted to
    # the summary figures judge the model on the samples it is for (a scene's subset, when it was fitted to one)
    used = fit_mask if fit_mask is not None else np.ones(len(slices), dtype=bool)
    ru = resid[used]
    info: dict[str, Any] = {
        "selection": {"criterion": "BIC = robust chi^2 + k ln(n)", "chosen": chosen.name, "reason": why,
                      "candidates": [r.summary() for r in ranked], "skipped": skipped},
        "residuals": {
            "n_values": int(ru.size),
            "fitted_to_values": chosen.n,
            "chi2_reduced": round(float(np.sum(ru ** 2)) / max(ru.size - chosen.k, 1), 6),
            "rms_normalised": round(float(np.sqrt(np.mean(ru ** 2))), 6),
            "max_abs_normalised": round(float(np.max(np.abs(ru))), 6),
            "relative_rmse_cos": round(relative_rmse_cos_dirs(model[used], f[used], wi[used], wo[used]), 6),
            "relative_rmse_cos_all_samples": round(relative_rmse_cos_dirs(model, f, wi, wo), 6),
            "samples_used": int(used.sum()),
            "samples": {"theta_i_deg": slices.theta_i_deg.tolist(), "theta_o_deg": slices.theta_o_deg.tolist(),
                        "normalised": np.round(resid, 5).tolist()},
        },
        "weights": {"sigma": f"sqrt(std^2 + ({rel:g} f_model)^2 + ({FLOOR:g} peak)^2)", "loss": loss,
                    "f_scale_sigma": f_scale},
        "fit": {"converged": chosen.success, "message": chosen.message, "evaluations": chosen.nfev},
        "holes": "the blind spot and missing samples are covered by the fitted model",
        "constraints": {
            "amplitudes": "lambert albedo, microfacet specular and retro amount each in (0, 1]",
            "fresnel": "Schlick's approximation of a dielectric interface: f0 = ((ior - 1) / (ior + 1))^2, "
                       f"ior in [{IOR_MIN:.3f}, {IOR_MAX:.0f}]",
            "energy": "each channel's directional albedo held <= 1 at theta_i = 0-88 deg during the fit",
            "max_directional_albedo": [round(float(v), 5) for v in chosen.albedo().max(axis=0)],
            **{k: round(v, 6) for k, v in gaps.items()},
        },
    }
    if scene_info is not None:
        info["scene"] = scene_info
    if notes:
        info["notes"] = notes
    channels = ["value"] if n_c == 1 else ["R", "G", "B"]
    return FitReconstruction(material, channels, chosen, info)
