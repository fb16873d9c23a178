"""A structured prior: materials as a few physically meaningful factors, the prior over the factors.

Every prior material and channel is expressed, in the mapped space of :mod:`reconstruction.methods.prior`
(y = log(f cos theta_i cos theta_o / s + EPS)), by a two-term model of short vectors

    f cos theta_i cos theta_o / s = cos theta_i cos theta_o exp(A(theta_d))            diffuse and retro part
                                    + G(wi, wo) exp(D(theta_h) + F(theta_d))           microfacet part

with A, F piecewise linear over :data:`KNOTS_D` (theta_d, deg; F(0) = 0: the level is D's), D piecewise linear
over :data:`KNOTS_H` (u = sqrt(theta_h / 90 deg), MERL's own theta_h axis, dense near the peak) and G the
V-cavity shadowing min(1, 2 cos theta_h cos theta_o / cos theta_d, 2 cos theta_h cos theta_i / cos theta_d)
(no parameter). D is the log of the microfacet distribution times the level, F the log of a Fresnel-like factor,
A the log of a diffuse albedo that may rise (retro-reflection, small theta_d) or fall with theta_d: 25 numbers per
channel (:data:`N_PARAMS`). Each prior row is fitted once (:func:`fit_factors`; Levenberg-Marquardt on a fixed
subset of the training cells); the prior is the Gaussian of those vectors (mean and covariance, shrunk).

A sample's factors are the maximum a posteriori fit to its mapped values (:func:`map_factors`: Gauss-Newton in
the factors with the Gaussian's penalty, noise variance ``lam`` in the mapped space), started from the prior
mean and from the nearest prior row; the table is the model everywhere. What one slice says about the lobe's
shape over theta_h is carried to incidences it did not see by the model itself, the theta_d factors by the prior.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from reconstruction.core.geometry import half_diff_from_dirs
from reconstruction.core.samples import sample_directions
from reconstruction.core.slicedata import Slice
from reconstruction.methods import prior as P

Array = NDArray[np.float64]

__all__ = ["KNOTS_D", "KNOTS_H", "N_PARAMS", "LAM", "SHRINK", "Features", "features", "grid_features",
           "model_mapped", "model_mapped_rows", "fit_factors", "StructuredPrior", "structured_prior", "map_factors",
           "reconstruct_structured"]

KNOTS_D = np.array([0.0, 20.0, 40.0, 55.0, 65.0, 75.0, 90.0])  #: theta_d knots of A and F (deg)
KNOTS_H = np.array([0.0, 0.03, 0.06, 0.1, 0.15, 0.2, 0.3, 0.4, 0.55, 0.7, 0.85, 1.0])  #: u = sqrt(theta_h / 90 deg)
NA, NH, NF = KNOTS_D.size, KNOTS_H.size, KNOTS_D.size - 1
N_PARAMS = NA + NH + NF  #: factors per channel: A (7), D (12), F (6)
#: noise variance of the mapped samples in :func:`map_factors` (ln units squared); chosen among 0.01/0.03/0.1/0.3 on
#: 13 real materials the evaluation leaves out (bench_prior_candidates.py --dev --every 9 --offset 1 --slices 1,2)
LAM = 0.03
SHRINK = 0.05  #: the prior covariance is (1 - SHRINK) C + SHRINK diag(C) (C: the rows' sample covariance)
FIT_CELLS = 6000  #: training cells a prior row is fitted on (a fixed random subset)
RIDGE = 1e-3  #: a prior row's fit: weight of a pull towards :func:`_start` (only where the data say nothing)


def _hats(x: Array, knots: Array) -> Array:
    """Piecewise-linear hat functions (n, K) of the knots at ``x`` (n,) (clipped to the knots' range)."""
    x = np.clip(x, knots[0], knots[-1])
    j = np.clip(np.searchsorted(knots, x, side="right") - 1, 0, knots.size - 2)
    t = (x - knots[j]) / (knots[j + 1] - knots[j])
    out = np.zeros((x.size, knots.size))
    rows = np.arange(x.size)
    out[rows, j] = 1.0 - t
    out[rows, j + 1] = t
    return out


@dataclass
class Features:
    """What the model needs of a set of direction pairs: hat functions over theta_d (n, NA) and over u (n, NH),
    cos theta_i cos theta_o (n,) and the V-cavity G (n,)."""

    hd: Array
    hh: Array
    cc: Array
    g: Array

    def take(self, sel: NDArray[np.intp] | NDArray[np.bool_]) -> Features:
        return Features(self.hd[sel], self.hh[sel], self.cc[sel], self.g[sel])


def features(wi: Array, wo: Array) -> Features:
    """:class:`Features` of the pairs (n, 3) of unit vectors (local frame, z = normal)."""
    th, _, td, _ = half_diff_from_dirs(wi, wo)
    ci, co = np.clip(wi[:, 2], 0.0, 1.0), np.clip(wo[:, 2], 0.0, 1.0)
    ch, cd = np.cos(th), np.maximum(np.cos(td), 1e-6)
    g = np.minimum(1.0, np.minimum(2.0 * ch * co / cd, 2.0 * ch * ci / cd))
    u = np.sqrt(np.clip(th, 0.0, np.pi / 2) / (np.pi / 2))
    return Features(_hats(np.degrees(td), KNOTS_D), _hats(u, KNOTS_H), ci * co, g)


@lru_cache(maxsize=1)
def grid_features() -> Features:
    """:class:`Features` of the reduced grid's training cells (M rows)."""
    g = P._grid()
    return features(g["wi"][g["train"]], g["wo"][g["train"]])


def _split(p: Array) -> tuple[Array, Array, Array]:
    """(A (..., NA), D (..., NH), F (..., NA) with F(0) = 0) of factor vectors (..., N_PARAMS)."""
    a, d, f = p[..., :NA], p[..., NA:NA + NH], p[..., NA + NH:]
    return a, d, np.concatenate([np.zeros((*f.shape[:-1], 1)), f], axis=-1)


def _terms(p: Array, ft: Features) -> tuple[Array, Array]:
    """The diffuse and microfacet terms (n,) of f cos cos / s for one factor vector."""
    a, d, f = _split(p)
    return ft.cc * np.exp(np.clip(ft.hd @ a, -60, 60)), ft.g * np.exp(np.clip(ft.hh @ d + ft.hd @ f, -60, 60))


def model_mapped(p: Array, ft: Features) -> Array:
    """The model's mapped values log(f cos cos / s + EPS) (n,) for the factors ``p`` (N_PARAMS,)."""
    t1, t2 = _terms(p, ft)
    return np.log(t1 + t2 + P.EPS)


def model_mapped_rows(rows: Array, ft: Features) -> Array:
    """:func:`model_mapped` of many factor vectors ``rows`` (T, N_PARAMS) at once: (T, n)."""
    a, d, f = _split(rows)
    t1 = ft.cc[None] * np.exp(np.clip(a @ ft.hd.T, -60, 60))
    t2 = ft.g[None] * np.exp(np.clip(d @ ft.hh.T + f @ ft.hd.T, -60, 60))
    return np.log(t1 + t2 + P.EPS)


def _jac(p: Array, ft: Features) -> Array:
    """d model_mapped / d p, (n, N_PARAMS)."""
    t1, t2 = _terms(p, ft)
    den = 1.0 / (t1 + t2 + P.EPS)
    ja = ft.hd * (t1 * den)[:, None]
    js = (t2 * den)[:, None]
    return np.concatenate([ja, ft.hh * js, ft.hd[:, 1:] * js], axis=1)


def _start() -> Array:
    """A generic starting point: a diffuse level 1 (the scale), a falling lobe, F = 0."""
    return np.concatenate([np.zeros(NA), -2.0 - 12.0 * KNOTS_H, np.zeros(NF)])


def fit_factors(y: Array, ft: Features, x0: Array | None = None, prior: tuple[Array, Array] | None = None,
                lam: float = LAM) -> Array:
    """The factors (N_PARAMS,) that fit mapped values ``y`` (n,) at pairs ``ft``: least squares, with
    ``prior`` = (mean (N_PARAMS,), whitening W (N_PARAMS, N_PARAMS) with W^T W the inverse covariance) the MAP
    estimate for noise variance ``lam``, else a weak pull (:data:`RIDGE`) towards the start."""
    x0 = _start() if x0 is None else np.asarray(x0, dtype=np.float64)
    if prior is None:
        mu, wmat, wn = _start(), np.eye(N_PARAMS) * np.sqrt(RIDGE * y.size), 1.0
    else:
        (mu, wmat), wn = prior, 1.0 / np.sqrt(lam)

    def fun(p: Array) -> Array:
        return np.concatenate([(model_mapped(p, ft) - y) * wn, wmat @ (p - mu)])

    def jac(p: Array) -> Array:
        return np.concatenate([_jac(p, ft) * wn, wmat], axis=0)

    return least_squares(fun, x0, jac=jac, method="lm", max_nfev=200 if prior is None else 100).x


@lru_cache(maxsize=1)
def _fit_cells() -> NDArray[np.intp]:
    """The fixed subset of training cells a prior row is fitted on (:data:`FIT_CELLS`, seed 0)."""
    m = int(P._grid()["train"].sum())
    return np.sort(np.random.default_rng(0).choice(m, size=min(FIT_CELLS, m), replace=False))


@dataclass
class StructuredPrior:
    """Every prior row's factors: ``names`` (N), ``factors`` (N, C, N_PARAMS) at each row's own ``scales`` (N, C):
    the median of its f cos cos over the 40 deg in-plane cells (:func:`reference_scales`)."""

    names: list[str]
    factors: Array
    scales: Array

    def gaussian(self, exclude: tuple[str, ...] = (), at: Features | None = None) -> tuple[Array, Array, Array]:
        """(mean (N_PARAMS,), whitening W (N_PARAMS, N_PARAMS), the rows (T, N_PARAMS)) over the rows of every
        material not in ``exclude``. With ``at`` (the samples' pairs), each row is first brought to the scale a
        sample of that geometry gets (its model's median of f cos cos there: A and D shifted by minus its log)."""
        keep = [i for i, n in enumerate(self.names) if n not in set(exclude)]
        rows = self.factors[keep].reshape(-1, N_PARAMS).copy()
        if at is not None:
            med = np.median(np.exp(model_mapped_rows(rows, at)) - P.EPS, axis=1)
            rows[:, :NA + NH] -= np.log(np.maximum(med, 1e-12))[:, None]
        mu = rows.mean(axis=0)
        c = np.cov(rows, rowvar=False)
        c = (1.0 - SHRINK) * c + SHRINK * np.diag(np.diag(c)) + 1e-6 * np.eye(N_PARAMS)
        return mu, np.linalg.cholesky(np.linalg.inv(c)).T, rows


def reference_scales(ps: P.PriorSet) -> Array:
    """(N, C) the scale of every prior row: the median of f cos cos over the 40 deg in-plane cells (as the floors
    of benchmarks/bench_prior_floor.py scale a material)."""
    to = np.arange(-80.0, 80.0 + 1e-9, 2.0)
    to = to[np.abs(to + 40.0) >= 4.0]
    s = Slice(np.full(to.size, 40.0), to, np.ones((to.size, 1)), ["value"])
    idx, w, _ = P._design(s)
    fc = ps._fc()
    at = np.einsum("nj,tnj->tn", w, fc[:, idx]).astype(np.float64)
    return P.channel_scales(at.reshape(len(ps.names), ps.tables.shape[1], -1))


def structured_prior(ps: P.PriorSet) -> StructuredPrior:
    """Fit every row of ``ps`` (about 0.3 s a row on one core): :class:`StructuredPrior`."""
    sc = reference_scales(ps)
    cells = _fit_cells()
    ft = grid_features().take(cells)
    fc = ps._fc()
    nc = ps.tables.shape[1]
    out = np.zeros((len(ps.names), nc, N_PARAMS))
    for t in range(fc.shape[0]):  # one least-squares fit per row (material x channel)
        m, c = divmod(t, nc)
        y = np.log(fc[t, cells].astype(np.float64) / sc[m, c] + P.EPS)
        out[m, c] = fit_factors(y, ft)
    return StructuredPrior(list(ps.names), out, sc)


def map_factors(y: Array, ft: Features, gauss: tuple[Array, Array, Array], lam: float = LAM) -> Array:
    """The MAP factors (N_PARAMS,) of mapped values ``y`` (n,) at ``ft`` under the Gaussian ``gauss`` (mean,
    whitening, rows): the better of the fits started from the mean and from the row nearest to ``y``."""
    mu, wmat, rows = gauss
    nearest = rows[int(np.argmin(np.mean((model_mapped_rows(rows, ft) - y) ** 2, axis=1)))]
    starts = [mu, nearest]
    best, cost = mu, np.inf
    for x0 in starts:
        p = fit_factors(y, ft, x0=x0, prior=(mu, wmat), lam=lam)
        c = np.sum((model_mapped(p, ft) - y) ** 2) / lam + np.sum((wmat @ (p - mu)) ** 2)
        if c < cost:
            best, cost = p, c
    return best


def reconstruct_structured(s: Slice, sp: StructuredPrior, exclude: tuple[str, ...] = (), lam: float = LAM
                           ) -> P.PriorReconstruction:
    """The factors of each channel of ``s`` (f_r) by :func:`map_factors` under the Gaussian of the prior's factors
    ``sp`` (:func:`structured_prior`; the materials in ``exclude`` left out), the model tabulated on the reduced
    grid."""
    from reconstruction.core.samples import everywhere

    s, _ = P._within_basis(everywhere(s))
    wi, wo = sample_directions(s)
    ft = features(wi, wo)
    obs = np.maximum(np.asarray(s.values, dtype=np.float64), 0.0) * ft.cc[:, None]
    scale = P.channel_scales(obs.T)
    y = np.log(obs.T / scale[:, None] + P.EPS)  # (C, n)
    gauss = sp.gaussian(exclude, ft)
    params = np.stack([map_factors(y[c], ft, gauss, lam) for c in range(y.shape[0])])
    return tabulate(params, scale, list(s.channels), {"parameters": {"lam": lam, "factors": N_PARAMS},
                                                        "factors": params.tolist()})


def tabulate(params: Array, scale: Array, channels: list[str], info: dict[str, object]) -> P.PriorReconstruction:
    """The model of factors ``params`` (C, N_PARAMS) at scales ``scale`` (C,) on the reduced grid (beyond 81 deg
    the last value along theta_d)."""
    g = P._grid()
    ft = grid_features()
    f = np.zeros((params.shape[0], g["cos"].size))
    mapped = np.stack([model_mapped(p, ft) for p in params])
    f[:, g["train"]] = np.maximum(np.exp(mapped) - P.EPS, 0.0) * scale[:, None] / g["cos"][g["train"]]
    f = np.where(g["cos"] > 0, P._extend(f), 0.0)
    return P.PriorReconstruction(channels, f, dict(info), method="prior-structured")
