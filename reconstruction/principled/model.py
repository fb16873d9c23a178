"""The principled material: OpenPBR Surface's opaque parameters (the reference model; Autodesk Standard Surface,
Blender's Principled BSDF and glTF 2.0 with its KHR_materials extensions map onto it, docs/formats.md) and a
vectorised evaluation of its BRDF.

Layers, top to bottom, each taking from the ones below what it reflects (albedo scaling, as Blender's Cycles
and glTF layer them; the albedos are :mod:`reconstruction.principled.albedo`'s tables, at the view direction wo):

    f = fuzz_weight fuzz_color f_sheen + (1 - fuzz_weight max(fuzz_color) E_sheen(mu_o)) [
          coat_weight f_coat + (1 - coat_weight E_coat(mu_o)) [
            metalness f_metal + (1 - metalness) (f_spec + (1 - max_c E_spec,c(mu_o)) f_diffuse) ] ]

- f_spec: GGX (alpha = specular_roughness^2), height-correlated Smith G2, Fresnel F0' + (1 - F0') s(theta_d)
  with F0' = specular_weight F0(specular_ior) specular_color and s the exact dielectric Fresnel of the index whose
  F0 is specular_weight F0(specular_ior), remapped to [0, 1] (Cycles' Principled form; untinted it is that
  index's exact Fresnel).
- f_metal: the same GGX with the F82-tint Fresnel (Kutz et al. 2021; OpenPBR, Cycles): F0 = base_weight
  base_color, tint specular_color at 82 deg.
- f_diffuse: base_weight base_color times EON, the energy-preserving Oren-Nayar of OpenPBR (Portsmouth et al.
  2025) with base_diffuse_roughness (0: Lambert).
- f_coat: GGX (coat_roughness^2) with the exact dielectric Fresnel of coat_ior; coat_color tints what is below
  by absorption along the refracted view path, coat_color^(1 / cos theta_t) (Cycles' coat tint).
- f_sheen: the Charlie distribution (alpha = fuzz_roughness^2) with Neubelt's visibility (glTF's sheen; OpenPBR
  and Blender use Zeltner's microfiber lobe, of similar shape).

The model is evaluated with wo the view direction (the albedo scaling makes it slightly non-reciprocal, as in
every renderer that layers this way). Units: f_r in 1/sr; directions are unit vectors in the local frame
(z = the normal).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass, fields
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.principled import albedo as alb

Array = NDArray[np.float64]

__all__ = ["MODEL", "MODEL_VERSION", "RANGES", "COLOUR_FIELDS", "PrincipledParams", "Geometry", "evaluate",
           "ParameterError"]

MODEL = "OpenPBR Surface"
MODEL_VERSION = "1.1"

#: the documented range of each parameter (OpenPBR Surface 1.1; specular_weight and the two indices of
#: refraction at their soft ranges, which every target format accepts)
RANGES: dict[str, tuple[float, float]] = {
    "base_weight": (0.0, 1.0), "base_color": (0.0, 1.0), "base_metalness": (0.0, 1.0),
    "base_diffuse_roughness": (0.0, 1.0),
    "specular_weight": (0.0, 1.0), "specular_color": (0.0, 1.0), "specular_roughness": (0.0, 1.0),
    "specular_ior": (1.0, 3.0),
    "coat_weight": (0.0, 1.0), "coat_color": (0.0, 1.0), "coat_roughness": (0.0, 1.0), "coat_ior": (1.0, 3.0),
    "fuzz_weight": (0.0, 1.0), "fuzz_color": (0.0, 1.0), "fuzz_roughness": (0.0, 1.0),
}
COLOUR_FIELDS = ("base_color", "specular_color", "coat_color", "fuzz_color")


class ParameterError(ValueError):
    """A parameter is missing, of the wrong kind or outside its documented range; the message names it."""


@dataclass(frozen=True)
class PrincipledParams:
    """OpenPBR Surface parameters (names as OpenPBR spells them; colours linear RGB in [0, 1]). Defaults are
    OpenPBR's, except fuzz and coat weights 0."""

    base_weight: float = 1.0
    base_color: tuple[float, float, float] = (0.8, 0.8, 0.8)
    base_metalness: float = 0.0
    base_diffuse_roughness: float = 0.0
    specular_weight: float = 1.0
    specular_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    specular_roughness: float = 0.3
    specular_ior: float = 1.5
    coat_weight: float = 0.0
    coat_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    coat_roughness: float = 0.0
    coat_ior: float = 1.6
    fuzz_weight: float = 0.0
    fuzz_color: tuple[float, float, float] = (1.0, 1.0, 1.0)
    fuzz_roughness: float = 0.5

    def __post_init__(self) -> None:
        for f in fields(self):
            v = getattr(self, f.name)
            lo, hi = RANGES[f.name]
            vals = v if f.name in COLOUR_FIELDS else (v,)
            if f.name in COLOUR_FIELDS and (not isinstance(v, tuple) or len(v) != 3):
                raise ParameterError(f"{f.name}: expected 3 numbers (linear RGB), got {v!r}")
            for x in vals:
                if isinstance(x, bool) or not isinstance(x, (int, float, np.floating)) or not math.isfinite(x):
                    raise ParameterError(f"{f.name}: expected a finite number, got {x!r}")
                if not lo <= float(x) <= hi:
                    raise ParameterError(f"{f.name}: {float(x):g} is outside its range [{lo:g}, {hi:g}]")

    def to_dict(self) -> dict[str, Any]:
        """Plain floats and lists (JSON)."""
        d = asdict(self)
        return {k: ([float(x) for x in v] if isinstance(v, tuple) else float(v)) for k, v in d.items()}

    @classmethod
    def from_dict(cls, d: dict[str, Any]) -> PrincipledParams:
        """From :meth:`to_dict`'s form; :class:`ParameterError` naming an unknown or bad key."""
        names = {f.name for f in fields(cls)}
        unknown = sorted(set(d) - names)
        if unknown:
            raise ParameterError(f"unknown parameter(s) {', '.join(unknown)}; expected {', '.join(sorted(names))}")
        kw = {k: (tuple(float(x) for x in v) if k in COLOUR_FIELDS and isinstance(v, (list, tuple)) else v)
              for k, v in d.items()}
        return cls(**kw)

    @property
    def specular_f0(self) -> float:
        """The dielectric's normal-incidence reflectance specular_weight F0(specular_ior) (untinted)."""
        return float(self.specular_weight * alb.f0_from_ior(self.specular_ior))

    def eval(self, wi: ArrayLike, wo: ArrayLike) -> Array:
        """f_r (N, 3) in 1/sr at unit direction pairs ``wi``, ``wo`` (N, 3) of the local frame (wo: the view)."""
        return evaluate(self, Geometry.of(wi, wo))


@dataclass(frozen=True)
class Geometry:
    """What the BRDF needs of direction pairs, computed once for many evaluations (a fit): cosines (N,) of
    theta_i, theta_o, theta_h, theta_d, sin theta_h, and s = wi.wo - mu_i mu_o (the EON's azimuthal term)."""

    mu_i: Array
    mu_o: Array
    cos_h: Array
    cos_d: Array
    sin_h: Array
    s: Array
    above: Array

    @classmethod
    def of(cls, wi: ArrayLike, wo: ArrayLike) -> Geometry:
        wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
        h = wi + wo
        hn = np.linalg.norm(h, axis=-1)
        h = h / np.maximum(hn, 1e-300)[:, None]
        above = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        mu_i, mu_o = np.clip(wi[:, 2], 1e-6, 1.0), np.clip(wo[:, 2], 1e-6, 1.0)
        cos_h = np.clip(h[:, 2], 0.0, 1.0)
        return cls(mu_i=mu_i, mu_o=mu_o, cos_h=cos_h, cos_d=np.clip(np.sum(wi * h, axis=-1), 0.0, 1.0),
                   sin_h=np.sqrt(np.clip(1.0 - cos_h * cos_h, 0.0, 1.0)),
                   s=np.sum(wi * wo, axis=-1) - mu_i * mu_o, above=above)


def _ggx_dg(g: Geometry, roughness: float) -> Array:
    """D G2 / (4 mu_i mu_o) of GGX (height-correlated Smith), (N,)."""
    a = max(roughness * roughness, alb.ALPHA_MIN)
    g2 = 1.0 / (1.0 + alb.ggx_lambda(g.mu_i, a) + alb.ggx_lambda(g.mu_o, a))
    return alb.ggx_d(g.cos_h, a) * g2 / (4.0 * g.mu_i * g.mu_o)


def _f82(cos_d: Array, f0: Array, tint: Array) -> Array:
    """The F82-tint Fresnel (N, 3) of a metal with normal reflectance ``f0`` (3,) and tint (3,) at 82 deg."""
    mu_bar = 1.0 / 7.0
    schlick = lambda mu: f0 + (1.0 - f0) * (1.0 - mu) ** 5  # noqa: E731
    a = schlick(mu_bar) * (1.0 - tint) / (mu_bar * (1.0 - mu_bar) ** 6)
    c = cos_d[:, None]
    return np.clip(schlick(c) - a * c * (1.0 - c) ** 6, 0.0, 1.0)


_FON_1 = 0.5 - 2.0 / (3.0 * math.pi)
_FON_2 = 2.0 / 3.0 - 28.0 / (15.0 * math.pi)


def _eon(g: Geometry, rho: Array, r: float) -> Array:
    """EON (energy-preserving Oren-Nayar, OpenPBR) (N, 3) of albedo ``rho`` (3,) and roughness ``r``; Lambert
    rho / pi at r = 0."""
    if r <= 0.0:
        return np.broadcast_to(rho / math.pi, (g.mu_i.size, 3))
    a_f = 1.0 / (1.0 + _FON_1 * r)
    s_over_t = np.where(g.s > 0, g.s / np.maximum(np.maximum(g.mu_i, g.mu_o), 1e-12), g.s)
    f_ss = (rho / math.pi)[None, :] * (a_f * (1.0 + r * s_over_t))[:, None]

    def e_fon(mu: Array) -> Array:
        m = 1.0 - mu
        g_over_pi = m * (0.0571085289 + m * (0.491881867 + m * (-0.332181442 + m * 0.0714429953)))
        return (1.0 + r * g_over_pi) / (1.0 + _FON_1 * r)

    avg = a_f * (1.0 + _FON_2 * r)
    rho_ms = rho * rho * avg / (1.0 - rho * (1.0 - avg))
    eps = 1e-7
    ms = np.maximum(eps, 1.0 - e_fon(g.mu_o)) * np.maximum(eps, 1.0 - e_fon(g.mu_i)) / max(eps, 1.0 - avg)
    return f_ss + (rho_ms / math.pi)[None, :] * ms[:, None]


def evaluate(p: PrincipledParams, g: Geometry) -> Array:
    """f_r (N, 3) in 1/sr of the material ``p`` at the pairs of ``g`` (0 below the horizon); see the module
    docstring for the layers."""
    n = g.mu_i.size
    base_color = p.base_weight * np.asarray(p.base_color, dtype=np.float64)
    spec_tint = np.asarray(p.specular_color, dtype=np.float64)
    out = np.zeros((n, 3))
    metal = p.base_metalness
    dg = _ggx_dg(g, p.specular_roughness)
    if metal < 1.0:
        f0 = min(p.specular_f0, alb.F0_MAX)
        f0t = f0 * spec_tint
        eta = float(alb.ior_from_f0(f0))
        fr = alb.fresnel_dielectric(g.cos_d, eta)
        s = (fr - f0) / (1.0 - f0) if f0 > 0 else np.zeros(n)
        spec = dg[:, None] * (f0t[None, :] + (1.0 - f0t[None, :]) * s[:, None]) if f0 > 0 else np.zeros((n, 3))
        e1, sv = alb.ggx_albedo(p.specular_roughness, f0)
        e_spec = alb.curve(e1, g.mu_o) * float(np.max(f0t)) + alb.curve(sv, g.mu_o) * (1.0 - float(np.max(f0t)))
        e_spec = e_spec if f0 > 0 else np.zeros(n)
        diffuse = _eon(g, base_color, p.base_diffuse_roughness)
        out += (1.0 - metal) * (spec + np.clip(1.0 - e_spec, 0.0, 1.0)[:, None] * diffuse)
    if metal > 0.0:
        out += metal * p.specular_weight * dg[:, None] * _f82(g.cos_d, np.clip(base_color, 0, 1), spec_tint)
    if p.coat_weight > 0.0:
        cf0 = float(alb.f0_from_ior(p.coat_ior))
        coat = _ggx_dg(g, p.coat_roughness) * alb.fresnel_dielectric(g.cos_d, p.coat_ior)
        e1, sv = alb.ggx_albedo(p.coat_roughness, cf0)
        e_coat = alb.curve(e1, g.mu_o) * cf0 + alb.curve(sv, g.mu_o) * (1.0 - cf0)
        below = np.clip(1.0 - p.coat_weight * e_coat, 0.0, 1.0)[:, None]
        tint = np.asarray(p.coat_color, dtype=np.float64)
        if np.any(tint != 1.0):  # absorption along the refracted view path (Cycles' coat tint)
            cos_t = np.sqrt(1.0 - (1.0 - g.mu_o ** 2) / p.coat_ior ** 2)
            below = below * (1.0 - p.coat_weight + p.coat_weight * np.power(tint[None, :], 1.0 / cos_t[:, None]))
        out = p.coat_weight * coat[:, None] + below * out
    if p.fuzz_weight > 0.0:
        fc = np.asarray(p.fuzz_color, dtype=np.float64)
        sheen = alb.charlie_d(g.sin_h, p.fuzz_roughness ** 2) * alb.sheen_visibility(g.mu_i, g.mu_o)
        e_sheen = alb.curve(alb.sheen_albedo(p.fuzz_roughness), g.mu_o)
        out = (p.fuzz_weight * sheen[:, None] * fc[None, :]
               + np.clip(1.0 - p.fuzz_weight * float(np.max(fc)) * e_sheen, 0.0, 1.0)[:, None] * out)
    return np.where(g.above[:, None], out, 0.0)
