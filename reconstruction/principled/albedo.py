"""Directional albedo tables of the principled model's layers (what each layer reflects, so the layers below get
the rest: albedo scaling, as OpenPBR, Blender's Principled BSDF and glTF's KHR_materials_sheen layer them).

Tables are built once per process (deterministic, about 0.2 s) by quadrature over GGX visible normals (Heitz
2018) and over a cosine-weighted lattice (sheen), and read by linear interpolation:

- :func:`ggx_albedo`: E(mu_o) = integral of D G2 F / (4 mu_i mu_o) mu_i d omega_i of the GGX lobe, for F = 1
  (``e1``) and for the dielectric Fresnel remapped to [0, 1] (``s``: (F(eta) - F0) / (1 - F0)), so that a lobe
  with the generalised Schlick Fresnel F0' + (1 - F0') s (Cycles' form; tint at normal incidence) reflects
  F0' e1 + (1 - F0') s.
- :func:`sheen_albedo`: the same for the Charlie sheen lobe with Neubelt's visibility (glTF KHR_materials_sheen).

Axes: mu = cos theta_o (unitless), roughness r in [0, 1] (alpha = r^2), F0 in [0, F0_MAX] (the dielectric's
normal-incidence reflectance, eta = (1 + sqrt F0) / (1 - sqrt F0)).
"""

from __future__ import annotations

import math
from functools import lru_cache

import numpy as np
from numpy.typing import NDArray

Array = NDArray[np.float64]

__all__ = ["MU", "ROUGHNESS", "F0_GRID", "F0_MAX", "ALPHA_MIN", "fresnel_dielectric", "ior_from_f0", "f0_from_ior",
           "ggx_albedo", "sheen_albedo", "charlie_d", "sheen_visibility", "ggx_d", "ggx_lambda", "curve"]

MU = np.linspace(0.02, 1.0, 33)
ROUGHNESS = np.linspace(0.0, 1.0, 26)
F0_MAX = 0.25  # an index of refraction of 3
F0_GRID = np.linspace(0.0, F0_MAX, 11)
ALPHA_MIN = 1e-4  # GGX alpha floor (a mirror is alpha 0: kept finite)
SHEEN_ALPHA_MIN = 0.07  # the Charlie distribution's floor (glTF viewers clamp similarly)


def f0_from_ior(eta: float | Array) -> Array:
    """Normal-incidence reflectance ((eta - 1) / (eta + 1))^2 of a dielectric of relative index ``eta``."""
    eta = np.asarray(eta, dtype=np.float64)
    return ((eta - 1.0) / (eta + 1.0)) ** 2


def ior_from_f0(f0: float | Array) -> Array:
    """The relative index of refraction eta >= 1 whose normal-incidence reflectance is ``f0`` in [0, 1)."""
    s = np.sqrt(np.clip(np.asarray(f0, dtype=np.float64), 0.0, 0.999999))
    return (1.0 + s) / (1.0 - s)


def fresnel_dielectric(cos_d: Array, eta: float | Array) -> Array:
    """Unpolarised Fresnel reflectance of a dielectric (relative index ``eta`` >= 1, light from outside) at the
    cosine ``cos_d`` of the angle to the microfacet normal."""
    c = np.clip(np.abs(cos_d), 0.0, 1.0)
    eta = np.asarray(eta, dtype=np.float64)
    g2 = eta * eta - 1.0 + c * c
    g = np.sqrt(np.clip(g2, 0.0, None))
    a = (g - c) / np.maximum(g + c, 1e-300)
    b = (c * (g + c) - 1.0) / np.maximum(c * (g - c) + 1.0, 1e-300)
    return np.where(g2 > 0, 0.5 * a * a * (1.0 + b * b), 1.0)


def ggx_d(cos_h: Array, alpha: float | Array) -> Array:
    """GGX (Trowbridge-Reitz) normal distribution D (1/sr) at cos theta_h."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    c2 = np.clip(cos_h, 0.0, 1.0) ** 2
    return a2 / (math.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)


def ggx_lambda(cos_v: Array, alpha: float | Array) -> Array:
    """Smith's Lambda of GGX at the direction of cosine ``cos_v`` (> 0)."""
    a2 = np.asarray(alpha, dtype=np.float64) ** 2
    c2 = np.clip(cos_v, 1e-12, 1.0) ** 2
    return 0.5 * (np.sqrt(1.0 + a2 * (1.0 - c2) / c2) - 1.0)


def charlie_d(sin_h: Array, alpha: float | Array) -> Array:
    """The Charlie sheen distribution (Estevez and Kulla 2017; glTF KHR_materials_sheen) at sin theta_h."""
    inv = 1.0 / np.maximum(np.asarray(alpha, dtype=np.float64), SHEEN_ALPHA_MIN)
    return (2.0 + inv) * np.power(np.clip(sin_h, 1e-12, 1.0), inv) / (2.0 * math.pi)


def sheen_visibility(mu_i: Array, mu_o: Array) -> Array:
    """Neubelt and Pettineo's sheen visibility 1 / (4 (mu_i + mu_o - mu_i mu_o)) (the glTF sheen's V)."""
    return 1.0 / (4.0 * np.maximum(mu_i + mu_o - mu_i * mu_o, 1e-12))


def _lattice(n: int) -> tuple[Array, Array]:
    k = np.arange(n, dtype=np.float64)
    return (k + 0.5) / n, np.mod(k * (math.sqrt(5.0) - 1.0) / 2.0 + 0.5 / n, 1.0)


@lru_cache(maxsize=1)
def _ggx_tables() -> tuple[Array, Array]:
    """(e1 (mu, r), s (mu, r, F0)) by VNDF quadrature: E = mean over visible normals of F G2 / G1(wo)."""
    n = 512
    u1, u2 = _lattice(n)
    mu = MU[:, None, None]
    alpha = np.maximum(ROUGHNESS[None, :, None] ** 2, ALPHA_MIN)
    sin_o = np.sqrt(1.0 - mu * mu)
    # the view stretched (wo in the x-z plane), Heitz 2018
    vx, vz = alpha * sin_o, mu * np.ones_like(alpha)
    inv = 1.0 / np.sqrt(vx * vx + vz * vz)
    vx, vz = vx * inv, vz * inv
    r, phi = np.sqrt(u1)[None, None, :], 2.0 * math.pi * u2[None, None, :]
    p1 = r * np.cos(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * np.sqrt(np.clip(1.0 - p1 * p1, 0.0, None)) + s * r * np.sin(phi)
    p3 = np.sqrt(np.clip(1.0 - p1 * p1 - p2 * p2, 0.0, None))
    mx, my, mz = alpha * (p3 * vx - p2 * vz), alpha * p1, np.clip(p2 * vx + p3 * vz, 0.0, None)
    norm = np.sqrt(mx * mx + my * my + mz * mz)
    mx, my, mz = mx / norm, my / norm, mz / norm
    cos_d = sin_o * mx + mu * mz  # wo . m
    mu_i = 2.0 * cos_d * mz - mu  # wi = 2 (wo.m) m - wo
    lam_o = ggx_lambda(mu, alpha)
    ok = mu_i > 0
    g2_over_g1 = np.where(ok, (1.0 + lam_o) / (1.0 + lam_o + ggx_lambda(np.where(ok, mu_i, 1.0), alpha)), 0.0)
    e1 = g2_over_g1.mean(axis=2)
    f0 = F0_GRID[None, None, None, :]
    eta = ior_from_f0(f0)
    fr = fresnel_dielectric(cos_d[..., None], eta)
    remapped = np.where(f0 < 1.0, (fr - f0) / (1.0 - f0), 1.0)
    remapped = np.where(F0_GRID[None, None, None, :] > 0, remapped, 0.0)
    s_tab = (g2_over_g1[..., None] * remapped).mean(axis=2)
    return e1, s_tab


@lru_cache(maxsize=1)
def _sheen_table() -> Array:
    """E of the Charlie sheen with Neubelt's visibility, (mu, r), by cosine-weighted quadrature."""
    n = 2048
    u1, u2 = _lattice(n)
    rr, ph = np.sqrt(u1), 2.0 * math.pi * u2
    wi = np.stack([rr * np.cos(ph), rr * np.sin(ph), np.sqrt(np.clip(1.0 - u1, 0.0, None))], axis=-1)  # (n, 3)
    mu = MU[:, None]
    wo = np.stack([np.sqrt(1.0 - mu * mu), np.zeros_like(mu), mu], axis=-1)  # (M, 1, 3)
    h = wi[None, :, :] + wo
    h = h / np.linalg.norm(h, axis=-1, keepdims=True)
    sin_h = np.sqrt(np.clip(1.0 - h[..., 2] ** 2, 0.0, 1.0))  # (M, n)
    vis = sheen_visibility(wi[None, :, 2], mu)
    out = np.empty((MU.size, ROUGHNESS.size))
    for j, r in enumerate(ROUGHNESS):  # 26 roughnesses, each a vectorised (M, n) quadrature
        # integral of f cos d omega = pi * mean over cosine-weighted directions of f
        out[:, j] = math.pi * (charlie_d(sin_h, r * r) * vis).mean(axis=1)
    return out


def _axis_weights(grid: Array, x: float) -> tuple[int, float]:
    """(lower index, fraction) of ``x`` on a uniform ``grid``, clamped to it."""
    t = (float(np.clip(x, grid[0], grid[-1])) - grid[0]) / (grid[1] - grid[0])
    i = min(int(t), grid.size - 2)
    return i, t - i


def curve(table_mu: Array, mu: Array) -> Array:
    """A table's curve over :data:`MU` (len(MU), ...) read at the cosines ``mu`` (N,) -> (N, ...), linearly
    (clamped to the grid)."""
    t = (np.clip(mu, MU[0], MU[-1]) - MU[0]) / (MU[1] - MU[0])
    i = np.minimum(t.astype(np.intp), MU.size - 2)
    w = (t - i).reshape((-1,) + (1,) * (table_mu.ndim - 1))
    return table_mu[i] * (1.0 - w) + table_mu[i + 1] * w


def ggx_albedo(roughness: float, f0: float) -> tuple[Array, Array]:
    """The curves (e1, s) over :data:`MU` of a GGX lobe of ``roughness`` whose dielectric has reflectance ``f0``
    (see the module docstring); a lobe with Fresnel F0' + (1 - F0') s reflects F0' e1 + (1 - F0') s."""
    e1, s = _ggx_tables()
    i, a = _axis_weights(ROUGHNESS, roughness)
    j, b = _axis_weights(F0_GRID, f0)
    e = e1[:, i] * (1 - a) + e1[:, i + 1] * a
    sv = ((s[:, i, j] * (1 - b) + s[:, i, j + 1] * b) * (1 - a)
          + (s[:, i + 1, j] * (1 - b) + s[:, i + 1, j + 1] * b) * a)
    return e, sv


def sheen_albedo(roughness: float) -> Array:
    """The curve over :data:`MU` of the Charlie sheen's albedo at ``roughness`` (colour 1)."""
    tab = _sheen_table()
    i, a = _axis_weights(ROUGHNESS, roughness)
    return tab[:, i] * (1 - a) + tab[:, i + 1] * a
