"""Directional albedo of unit lobes: the energy each lobe reflects, for energy-constrained fits.

The directional albedo of a lobe is a(theta_i) = integral of f(wi, wo) cos(theta_o) d omega_o over the upper
hemisphere (dimensionless; a passive BRDF has a <= 1 at every incidence). For lobes of unit amplitude:

* ``lambert``: exactly 1;
* ``ggx`` / ``beckmann`` (separable Smith G1, Walter et al. 2007) with Schlick's Fresnel
  F = f0 + (1 - f0)(1 - cos theta_d)^5: a = f0 E1 + (1 - f0) E5 with E1 the albedo for F = 1 and E5 the albedo
  for F = (1 - cos theta_d)^5. E1 and E5 are tabulated once over (theta_i, log alpha) and interpolated
  bilinearly;
* ``retro`` (normalised Phong about wi, exponent n): tabulated over (theta_i, log(1 + n)).

The tables are integrals over the half vector with the distribution's own inverse CDF (Gauss-Legendre in the
CDF variable and in the azimuth), so a lobe far narrower than any fixed grid (alpha = 1e-3) is integrated as
accurately as a broad one. Built on first use (about 0.3-0.5 s per table) and cached on disk
(:mod:`.cache`, keyed by this module's source), so a process pays it only on a new machine or a changed module.
"""

from __future__ import annotations

import hashlib
import math
from functools import lru_cache
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.cache import cached_arrays
from reconstruction.core.models import beckmann_g1_over_cos, ggx_g1_over_cos

Array = NDArray[np.float64]

__all__ = ["microfacet_albedo", "retro_albedo", "ALPHA_TABLE_RANGE", "EXPONENT_TABLE_MAX"]

ALPHA_TABLE_RANGE = (1e-4, 2.0)
EXPONENT_TABLE_MAX = 1e5
_N_TI, _N_A = 48, 48
_N_U, _N_PHI = 64, 64


def _ti_grid() -> Array:
    """Incidence nodes (radians), denser towards grazing where the albedo changes fastest."""
    return np.arccos(np.linspace(1.0, 0.01, _N_TI))


def _gauss01(n: int) -> tuple[Array, Array]:
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (x + 1.0), 0.5 * w


@lru_cache(maxsize=1)
def _source_key() -> str:
    """The cache key of every table here: this module's own source (its grids, integrands and constants)."""
    return hashlib.sha1(Path(__file__).read_bytes()).hexdigest()


@lru_cache(maxsize=2)
def _microfacet_tables(distribution: str) -> tuple[Array, Array, Array, Array]:
    """(theta_i nodes, log alpha nodes, E1, E5) with E* of shape (n_ti, n_alpha), from the disk cache."""
    ti, la, e1, e5 = cached_arrays(f"albedo-{distribution}", _source_key(), lambda: _build_microfacet(distribution))
    return ti, la, e1, e5


def _build_microfacet(distribution: str) -> tuple[Array, Array, Array, Array]:
    ti = _ti_grid()
    la = np.linspace(np.log(ALPHA_TABLE_RANGE[0]), np.log(ALPHA_TABLE_RANGE[1]), _N_A)
    u, wu = _gauss01(_N_U)
    phi = (np.arange(_N_PHI) + 0.5) / _N_PHI * 2 * np.pi  # periodic: the midpoint rule is spectrally accurate
    alpha = np.exp(la)[None, :, None, None]
    uu = u[None, None, :, None]
    # half vector from the distribution's CDF of D(h) cos(theta_h): GGX tan^2 = a^2 u / (1 - u),
    # Beckmann tan^2 = -a^2 ln(1 - u); then D cos(theta_h) d omega_h = du dphi / (2 pi)
    tan2 = alpha ** 2 * (uu / (1.0 - uu) if distribution == "ggx" else -np.log1p(-uu))
    cth = 1.0 / np.sqrt(1.0 + tan2)
    sth = np.sqrt(np.maximum(1.0 - cth * cth, 0.0))
    hx, hz = sth * np.cos(phi), cth  # (1, n_a, n_u, n_phi); h_y does not enter wi . h or wo_z
    g1 = ggx_g1_over_cos if distribution == "ggx" else beckmann_g1_over_cos
    e1 = np.empty((ti.size, la.size))
    e5 = np.empty_like(e1)
    for k, t in enumerate(ti):  # one vectorised (alpha x u x phi) integral per incidence
        wix, wiz = -np.sin(t), np.cos(t)
        c_d = wix * hx + wiz * hz  # wi . h
        woz = 2.0 * c_d * hz - wiz
        ok = (c_d > 0) & (woz > 0)
        # f cos_o d omega_o = D F G1 G1 / (4 ci co) co 4 (wo . h) d omega_h, with wo . h = wi . h
        a = alpha[0]  # (n_a, 1, 1): every alpha at once
        gi = g1(np.full(a.shape, wiz), a)
        go = g1(np.clip(woz[0], 0.0, 1.0), a)
        vals = np.where(ok[0], gi * go * np.clip(woz[0], 0.0, None) * c_d[0] / cth[0], 0.0)
        w = wu[None, :, None] / _N_PHI  # du dphi / (2 pi) with the midpoint rule in phi
        e1[k] = np.sum(vals * w, axis=(1, 2))
        f5 = (1.0 - np.clip(c_d[0], 0.0, 1.0)) ** 5
        e5[k] = np.sum(vals * f5 * w, axis=(1, 2))
    return ti, la, e1, e5


def _bilinear(x_nodes: Array, y_nodes: Array, table: Array, x: Array, y: float) -> Array:
    """Bilinear interpolation of ``table`` (n_x, n_y) at points ``x`` (any shape) and one ``y``, both held at
    the end nodes: the column at ``y`` first, then linear in x (the same values as interpolating each point in
    both axes, at a fraction of the cost inside a fit's loop)."""
    y = min(max(float(y), float(y_nodes[0])), float(y_nodes[-1]))
    j = min(max(int(np.searchsorted(y_nodes, y)) - 1, 0), y_nodes.size - 2)
    ty = (y - y_nodes[j]) / (y_nodes[j + 1] - y_nodes[j])
    column = (1.0 - ty) * table[:, j] + ty * table[:, j + 1]
    return np.interp(np.asarray(x, dtype=np.float64), x_nodes, column)


def microfacet_albedo(theta_i: ArrayLike, alpha: float, f0: float | None = None, distribution: str = "ggx"
                      ) -> Array:
    """Directional albedo of a unit-amplitude microfacet lobe at incidences ``theta_i`` (radians), shape of
    ``theta_i``. ``f0``: Schlick Fresnel at normal incidence (None: F = 1)."""
    if distribution not in ("ggx", "beckmann"):
        raise ValueError(f"unknown distribution {distribution!r}")
    ti_n, la_n, e1, e5 = _microfacet_tables(distribution)
    ti = np.asarray(theta_i, dtype=np.float64)
    la = math.log(min(max(alpha, ALPHA_TABLE_RANGE[0]), ALPHA_TABLE_RANGE[1]))
    a1 = _bilinear(ti_n, la_n, e1, ti, la)
    if f0 is None:
        return a1
    a5 = _bilinear(ti_n, la_n, e5, ti, la)
    return f0 * a1 + (1.0 - f0) * a5


@lru_cache(maxsize=1)
def _retro_table() -> tuple[Array, Array, Array]:
    """(theta_i nodes, log(1 + n) nodes, albedo (n_ti, n_n)) of the normalised retro lobe, from the disk cache."""
    ti, ln, out = cached_arrays("albedo-retro", _source_key(), _build_retro)
    return ti, ln, out


def _build_retro() -> tuple[Array, Array, Array]:
    ti = _ti_grid()
    ln = np.linspace(0.0, np.log1p(EXPONENT_TABLE_MAX), _N_A)
    n = np.expm1(ln)
    v, wv = _gauss01(_N_U)
    phi = (np.arange(_N_PHI) + 0.5) / _N_PHI * 2 * np.pi
    # v = cos^(n+1) psi about wi: cos^n psi sin psi dpsi = dv / (n + 1)
    cpsi = v[None, :, None] ** (1.0 / (n[:, None, None] + 1.0))
    spsi = np.sqrt(np.maximum(1.0 - cpsi * cpsi, 0.0))
    out = np.empty((ti.size, n.size))
    for k, t in enumerate(ti):  # wo in a frame about wi = (-sin t, 0, cos t); only its z component matters
        woz = cpsi * np.cos(t) + spsi * np.cos(phi)[None, None, :] * np.sin(t)
        integ = np.sum(np.clip(woz, 0.0, None) * wv[None, :, None], axis=(1, 2)) * (2 * np.pi / _N_PHI)
        out[k] = (n + 2.0) / (2 * np.pi * (n + 1.0)) * integ
    return ti, ln, out


def retro_albedo(theta_i: ArrayLike, exponent: float) -> Array:
    """Directional albedo of a unit-amount retro lobe (exponent >= 0) at incidences ``theta_i`` (radians)."""
    ti_n, ln_n, tab = _retro_table()
    ti = np.asarray(theta_i, dtype=np.float64)
    ln = math.log1p(min(max(exponent, 0.0), EXPONENT_TABLE_MAX))
    return _bilinear(ti_n, ln_n, tab, ti, ln)
