"""Analytic BRDF lobes and materials (sums of lobes), all vectorised over direction arrays.

Every lobe answers ``eval(wi, wo) -> (..., C)``: the BRDF f_r in 1/sr for unit directions ``wi``, ``wo``
of shape (..., 3) in the local frame (z = normal), 0 where either direction is below the horizon.
``C`` is the number of colour channels: 1 (grey), 3 (linear RGB) or a spectral grid.

A material is configured in TOML as ``[material]`` with ``[[material.lobes]]`` entries, see
:meth:`Material.from_dict`. The simulator uses these as ground truth and ``reconstruction.methods.fit`` fits them.
"""

from __future__ import annotations

import math
import sys
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.core.geometry import normalize
from reconstruction.schema.material import lobe_keys

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

Array = NDArray[np.float64]

__all__ = [
    "Colour",
    "Lobe",
    "Lambert",
    "OrenNayar",
    "Microfacet",
    "Phong",
    "Retro",
    "Tabulated",
    "Nbrdf",
    "NBRDF_SUFFIXES",
    "Material",
    "MaterialError",
    "ggx_d",
    "beckmann_d",
    "ggx_g1_over_cos",
    "beckmann_g1_over_cos",
    "schlick",
    "LOBE_TYPES",
]

_TINY = 1e-300


class MaterialError(ValueError):
    """A material description is invalid; the message names the source and the key."""


# --- colours ---------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Colour:
    """A colour value: 1 (grey), 3 (linear RGB) or a spectrum sampled at ``wavelengths_nm``."""

    values: Array
    wavelengths_nm: Array | None = None

    @property
    def n(self) -> int:
        return int(self.values.shape[0])

    @staticmethod
    def parse(value: Any, where: str, wavelengths_nm: Sequence[float] | None = None) -> Colour:
        """Parse a number, a list of 1 or 3 numbers, a list matching ``wavelengths_nm``, or
        ``{wavelengths_nm = [...], values = [...]}``."""
        wl = None
        if isinstance(value, Mapping):
            if set(value) != {"wavelengths_nm", "values"}:
                raise MaterialError(f"{where}: a spectrum needs exactly the keys wavelengths_nm and values")
            wl, value = value["wavelengths_nm"], value["values"]
        elif wavelengths_nm is not None and isinstance(value, Sequence) and len(value) not in (1, 3):
            wl = wavelengths_nm
        if isinstance(value, (int, float)) and not isinstance(value, bool):
            value = [value]
        if not isinstance(value, Sequence) or isinstance(value, str) or not value:
            raise MaterialError(f"{where}: expected a number or a list of numbers, got {value!r}")
        try:
            arr = np.array([float(x) for x in value], dtype=np.float64)
        except (TypeError, ValueError):
            raise MaterialError(f"{where}: expected numbers, got {value!r}") from None
        if not np.all(np.isfinite(arr)) or np.any(arr < 0):
            raise MaterialError(f"{where}: values must be finite and >= 0, got {value!r}")
        if wl is not None:
            wla = np.asarray(wl, dtype=np.float64)
            if wla.shape != arr.shape:
                raise MaterialError(
                    f"{where}: {arr.size} values for {wla.size} wavelengths_nm; they must match"
                )
            if np.any(np.diff(wla) <= 0):
                raise MaterialError(f"{where}: wavelengths_nm must increase strictly")
            return Colour(arr, wla)
        if arr.size not in (1, 3):
            raise MaterialError(
                f"{where}: {arr.size} values; give 1 (grey), 3 (RGB) or a spectrum with wavelengths_nm"
            )
        return Colour(arr)

    def on(self, n_channels: int, wavelengths_nm: Array | None) -> Array:
        """This colour as (n_channels,) on the material's channel layout (grey broadcasts)."""
        if self.n == 1:
            return np.full(n_channels, self.values[0])
        if self.wavelengths_nm is not None:
            assert wavelengths_nm is not None
            if self.wavelengths_nm.shape == wavelengths_nm.shape and np.allclose(
                self.wavelengths_nm, wavelengths_nm
            ):
                return self.values
            return np.interp(wavelengths_nm, self.wavelengths_nm, self.values)
        return self.values

# --- microfacet building blocks (Walter et al. 2007) -----------------------------------------------------

def ggx_d(cos_h: ArrayLike, alpha: float) -> Array:
    """GGX / Trowbridge-Reitz normal distribution D(h) (1/sr) from cos(theta_h)."""
    c2 = np.square(np.clip(np.asarray(cos_h, dtype=np.float64), 0.0, 1.0))
    a2 = alpha * alpha
    den = c2 * (a2 - 1.0) + 1.0
    return np.where(c2 > 0, a2 / (np.pi * np.maximum(den * den, _TINY)), 0.0)

def beckmann_d(cos_h: ArrayLike, alpha: float) -> Array:
    """Beckmann normal distribution D(h) (1/sr) from cos(theta_h)."""
    c = np.clip(np.asarray(cos_h, dtype=np.float64), 0.0, 1.0)
    c2 = c * c
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        tan2 = np.where(c2 > 0, (1.0 - c2) / np.maximum(c2, _TINY), np.inf)
        d = np.exp(-tan2 / (alpha * alpha)) / (np.pi * alpha * alpha * np.maximum(c2 * c2, _TINY))
    return np.where(c2 > 0, np.nan_to_num(d, nan=0.0, posinf=0.0), 0.0)

def ggx_g1_over_cos(cos_v: ArrayLike, alpha: float) -> Array:
    """Smith G1(v) / cos(theta_v) for GGX, in a form that stays finite at grazing angles.

    G1 = 2 / (1 + sqrt(1 + alpha^2 tan^2)), so G1 / cos = 2 / (cos + sqrt(alpha^2 + (1 - alpha^2) cos^2)).
    """
    c = np.clip(np.asarray(cos_v, dtype=np.float64), 0.0, 1.0)
    a2 = alpha * alpha
    return 2.0 / np.maximum(c + np.sqrt(a2 + (1.0 - a2) * c * c), _TINY)

def beckmann_g1_over_cos(cos_v: ArrayLike, alpha: float) -> Array:
    """Smith G1(v) / cos(theta_v) for Beckmann with Walter's rational approximation, finite at grazing."""
    c = np.clip(np.asarray(cos_v, dtype=np.float64), 0.0, 1.0)
    s = np.sqrt(np.maximum(1.0 - c * c, 0.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        a = np.where(s > 0, c / np.maximum(alpha * s, _TINY), np.inf)
        # For a < 1.6: G1 = (3.535 a + 2.181 a^2) / (1 + 2.276 a + 2.577 a^2); divide by cos = a * alpha * s.
        low = (3.535 + 2.181 * a) / (1.0 + 2.276 * a + 2.577 * a * a) / np.maximum(alpha * s, _TINY)
        high = 1.0 / np.maximum(c, _TINY)
    return np.where(a < 1.6, low, high)


def schlick(cos_d: ArrayLike, f0: float | None) -> Array | float:
    """Schlick's Fresnel F(theta_d) = f0 + (1 - f0)(1 - cos theta_d)^5; 1 when ``f0`` is None."""
    if f0 is None:
        return 1.0
    c = np.clip(np.asarray(cos_d, dtype=np.float64), 0.0, 1.0)
    return f0 + (1.0 - f0) * (1.0 - c) ** 5


# --- lobes -----------------------------------------------------------------------------------------------


def _cosines(wi: Array, wo: Array) -> tuple[Array, Array, Array]:
    ci = wi[..., 2]
    co = wo[..., 2]
    return ci, co, (ci > 0) & (co > 0)


@dataclass
class Lobe:
    """Base class: one additive term of a material. Subclasses implement :meth:`shape`."""

    type_name: ClassVar[str] = ""
    colour_keys: ClassVar[tuple[str, ...]] = ()
    colour: Colour = field(default_factory=lambda: Colour(np.ones(1)))

    def shape(self, wi: Array, wo: Array) -> Array:
        """Scalar lobe shape (...), 1/sr, before the colour factor."""
        raise NotImplementedError

    def eval(self, wi: ArrayLike, wo: ArrayLike, n_channels: int = 0, wavelengths_nm: Array | None = None
             ) -> Array:
        """BRDF (..., C) in 1/sr; C = ``n_channels`` or this lobe's own colour size."""
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        n = n_channels or self.colour.n
        s = self.shape(wi, wo)
        return s[..., None] * self.colour.on(n, wavelengths_nm)

    def params(self) -> dict[str, Any]:
        """Scalar parameters as a plain dict (for reports)."""
        return {}

    def to_dict(self) -> dict[str, Any]:
        d: dict[str, Any] = {"type": self.type_name}
        d.update(self.params())
        key = self.colour_keys[0] if self.colour_keys else "colour"
        if self.colour.wavelengths_nm is not None:
            d[key] = {"wavelengths_nm": self.colour.wavelengths_nm.tolist(), "values": self.colour.values.tolist()}
        else:
            d[key] = self.colour.values.tolist()
        return d


@dataclass
class Lambert(Lobe):
    """Ideal diffuse: f = albedo / pi."""

    type_name: ClassVar[str] = "lambert"
    colour_keys: ClassVar[tuple[str, ...]] = ("albedo",)

    def shape(self, wi: Array, wo: Array) -> Array:
        _, _, up = _cosines(wi, wo)
        return np.where(up, 1.0 / np.pi, 0.0)


@dataclass
class OrenNayar(Lobe):
    """Oren-Nayar rough diffuse (qualitative model), roughness ``sigma_deg`` (degrees)."""

    type_name: ClassVar[str] = "oren_nayar"
    colour_keys: ClassVar[tuple[str, ...]] = ("albedo",)
    sigma_deg: float = 20.0

    def shape(self, wi: Array, wo: Array) -> Array:
        ci, co, up = _cosines(wi, wo)
        s2 = math.radians(self.sigma_deg) ** 2
        a = 1.0 - 0.5 * s2 / (s2 + 0.33)
        b = 0.45 * s2 / (s2 + 0.09)
        ci_c = np.clip(ci, 1e-12, 1.0)
        co_c = np.clip(co, 1e-12, 1.0)
        si = np.sqrt(np.maximum(1.0 - ci_c * ci_c, 0.0))
        so = np.sqrt(np.maximum(1.0 - co_c * co_c, 0.0))
        # cos(phi_i - phi_o) from the projections on the surface; 0 when either is the normal.
        dot_xy = wi[..., 0] * wo[..., 0] + wi[..., 1] * wo[..., 1]
        sin_prod = si * so
        cos_dphi = np.divide(dot_xy, sin_prod, out=np.zeros_like(dot_xy), where=sin_prod > 1e-12)
        # sin(alpha) tan(beta) with alpha = max(theta_i, theta_o), beta = min(...)
        sin_alpha = np.maximum(si, so)
        tan_beta = np.where(ci_c > co_c, si / ci_c, so / co_c)
        val = (a + b * np.maximum(cos_dphi, 0.0) * sin_alpha * tan_beta) / np.pi
        return np.where(up, val, 0.0)

    def params(self) -> dict[str, Any]:
        return {"sigma_deg": self.sigma_deg}


@dataclass
class Microfacet(Lobe):
    """Microfacet specular: f = specular * F(theta_d) D(h) G1(wi) G1(wo) / (4 cos_i cos_o).

    ``distribution`` is "ggx" or "beckmann"; separable Smith G1 (Walter et al. 2007); Schlick F with
    ``f0`` (F = 1 when f0 is None).
    """

    type_name: ClassVar[str] = "ggx"
    colour_keys: ClassVar[tuple[str, ...]] = ("specular",)
    alpha: float = 0.1
    f0: float | None = None
    distribution: str = "ggx"

    def shape(self, wi: Array, wo: Array) -> Array:
        h = normalize(wi + wo)
        return self.shape_cosines(h[..., 2], np.sum(wi * h, axis=-1), wi[..., 2], wo[..., 2])

    def shape_half_diff(self, theta_h: ArrayLike, theta_d: ArrayLike, cos_i: ArrayLike, cos_o: ArrayLike) -> Array:
        """:meth:`shape` from the half-diff angles (radians) and cos theta_i, cos theta_o (broadcast against each
        other): D of theta_h and F of theta_d on their own axes, no direction vectors (a table's rows)."""
        return self.shape_cosines(np.cos(theta_h), np.cos(theta_d), np.asarray(cos_i, float), np.asarray(cos_o, float))

    def shape_cosines(self, cos_h: Array, cos_d: Array, ci: Array, co: Array) -> Array:
        """:meth:`shape` from cos theta_h, cos theta_d (wi . h), cos theta_i and cos theta_o."""
        d_fn, g1 = (ggx_d, ggx_g1_over_cos) if self.distribution == "ggx" else (beckmann_d, beckmann_g1_over_cos)
        f = schlick(cos_d, self.f0) * d_fn(cos_h, self.alpha) * (g1(ci, self.alpha) * g1(co, self.alpha)) / 4.0
        return np.where((ci > 0) & (co > 0), f, 0.0)

    def params(self) -> dict[str, Any]:
        p: dict[str, Any] = {"alpha": self.alpha}
        if self.f0 is not None:
            p["f0"] = self.f0
        return p

    def to_dict(self) -> dict[str, Any]:
        d = super().to_dict()
        d["type"] = self.distribution
        return d


@dataclass
class Phong(Lobe):
    """Normalised Phong about the mirror direction: f = specular (n + 2)/(2 pi) max(0, r . wo)^n."""

    type_name: ClassVar[str] = "phong"
    colour_keys: ClassVar[tuple[str, ...]] = ("specular",)
    exponent: float = 20.0

    def shape(self, wi: Array, wo: Array) -> Array:
        _, _, up = _cosines(wi, wo)
        r_dot = -wi[..., 0] * wo[..., 0] - wi[..., 1] * wo[..., 1] + wi[..., 2] * wo[..., 2]
        val = (self.exponent + 2.0) / (2.0 * np.pi) * np.maximum(r_dot, 0.0) ** self.exponent
        return np.where(up, val, 0.0)

    def params(self) -> dict[str, Any]:
        return {"exponent": self.exponent}


@dataclass
class Retro(Lobe):
    """Back-scatter about the incident direction: f = amount (n + 2)/(2 pi) max(0, wi . wo)^n."""

    type_name: ClassVar[str] = "retro"
    colour_keys: ClassVar[tuple[str, ...]] = ("amount",)
    exponent: float = 10.0

    def shape(self, wi: Array, wo: Array) -> Array:
        _, _, up = _cosines(wi, wo)
        dot = np.sum(wi * wo, axis=-1)
        val = (self.exponent + 2.0) / (2.0 * np.pi) * np.maximum(dot, 0.0) ** self.exponent
        return np.where(up, val, 0.0)

    def params(self) -> dict[str, Any]:
        return {"exponent": self.exponent}


def _rgb_on(rgb: Array, n_channels: int, what: str) -> Array:
    """An RGB lobe's values (..., 3) on a material of ``n_channels``: 3 as they are, 1 as their mean."""
    n = n_channels or 3
    if n == 3:
        return rgb
    if n == 1:
        return rgb.mean(axis=-1, keepdims=True)
    raise MaterialError(f"{what} gives RGB; it cannot be mixed with spectral lobes")


#: path -> MERL table (3, 90, 90, 180) in 1/sr for :class:`Tabulated`: formats.merl.read, registered on import.
TABLE_READER: Callable[[str], Array] | None = None


@dataclass
class Tabulated(Lobe):
    """A measured MERL table (linear RGB), looked up with trilinear interpolation; ``scale`` multiplies it."""

    type_name: ClassVar[str] = "tabulated"
    colour_keys: ClassVar[tuple[str, ...]] = ("scale",)
    path: str = ""
    table: Array | None = None

    def _table(self) -> Array:
        if self.table is None:
            assert TABLE_READER is not None, "importing reconstruction registers the MERL reader"
            self.table = TABLE_READER(self.path)
        return self.table

    def shape(self, wi: Array, wo: Array) -> Array:  # pragma: no cover - eval is overridden
        raise NotImplementedError

    def eval(self, wi: ArrayLike, wo: ArrayLike, n_channels: int = 0, wavelengths_nm: Array | None = None
             ) -> Array:
        from reconstruction.core import merltable

        wi, wo = np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64)
        rgb = np.nan_to_num(merltable.lookup(self._table(), wi, wo, interpolate=True), nan=0.0)
        return _rgb_on(rgb * self.colour.on(3, None), n_channels, "a tabulated lobe")

    def params(self) -> dict[str, Any]:
        return {"path": self.path}


def read_lobe_table(lobe: Lobe, where: str, record: bool = True) -> list[str]:
    """Read now the MERL table of a ``tabulated`` lobe (other lobes: nothing), not when it is first evaluated, so
    that a bench file whose table cannot be read is refused before anything starts, as both bench-file readers do.
    ``where`` names the lobe (``"[material].lobes[0]"``): a table that cannot be read raises
    :class:`~reconstruction.core.merltable.MerlError` ``"WHERE.path: why"``; with ``record`` the reader's warnings
    are returned as ``"WHERE.path: text"`` instead of warned."""
    import warnings

    from reconstruction.core.merltable import MerlError

    if not isinstance(lobe, Tabulated):
        return []
    assert TABLE_READER is not None, "importing reconstruction registers the MERL reader"
    try:
        if not record:
            lobe.table = TABLE_READER(lobe.path)
            return []
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            lobe.table = TABLE_READER(lobe.path)
    except MerlError as e:
        raise MerlError(f"{where}.path: {e}") from None
    return [f"{where}.path: {w.message}" for w in caught]


NBRDF_SUFFIXES = ("fc1", "b1", "fc2", "b2", "fc3", "b3")
_NBRDF_SHAPES = {"fc1": (6, 21), "b1": (21,), "fc2": (21, 21), "b2": (21,), "fc3": (21, 3), "b3": (3,)}


def _nbrdf_weights(prefix: str) -> dict[str, Array]:
    """The six arrays of a neural BRDF (``PREFIX_fc1.npy`` ... ``PREFIX_b3.npy``), checked for shape."""
    out: dict[str, Array] = {}
    for suffix in NBRDF_SUFFIXES:
        path = Path(f"{prefix}_{suffix}.npy")
        try:
            a = np.load(path, allow_pickle=False)
        except FileNotFoundError:
            raise MaterialError(f"{path}: no such file (a neural BRDF needs {prefix}_{{"
                                f"{','.join(NBRDF_SUFFIXES)}}}.npy)") from None
        except (OSError, ValueError) as e:
            raise MaterialError(f"{path}: not a readable .npy array ({e})") from None
        want = _NBRDF_SHAPES[suffix]
        if a.shape != want or not np.issubdtype(a.dtype, np.floating) or not np.all(np.isfinite(a)):
            raise MaterialError(f"{path}: expected finite floats of shape {want}, got {a.dtype} {a.shape}")
        out[suffix] = a.astype(np.float64)
    return out


def nbrdf_features(wi: Array, wo: Array) -> Array:
    """The neural BRDF's input (..., 6) at direction pairs (..., 3): x = (sin theta_h, 0, cos theta_h,
    sin theta_d cos phi_d, sin theta_d sin phi_d, cos theta_d), phi_d folded into [0, pi)."""
    from reconstruction.core.geometry import half_diff_from_dirs

    th, _, td, pd = half_diff_from_dirs(wi, wo)
    pd = np.mod(pd, np.pi)
    sd = np.sin(td)
    return np.stack([np.sin(th), np.zeros_like(th), np.cos(th), sd * np.cos(pd), sd * np.sin(pd), np.cos(td)], -1)


def nbrdf_forward(x: NDArray[np.floating], w: Mapping[str, Array]) -> Array:
    """f_r (..., 3) in 1/sr of the network ``w`` (:func:`_nbrdf_weights`) at the inputs ``x`` (...,
    6) of :func:`nbrdf_features`: two ReLU layers and max(exp(a2 fc3 + b3) - 1, 0), in the dtype of ``x``."""
    dt = x.dtype
    a1 = np.maximum(x @ w["fc1"].astype(dt) + w["b1"].astype(dt), 0.0)
    a2 = np.maximum(a1 @ w["fc2"].astype(dt) + w["b2"].astype(dt), 0.0)
    with np.errstate(over="ignore"):
        rgb = np.maximum(np.expm1(a2 @ w["fc3"].astype(dt) + w["b3"].astype(dt)), 0.0)
    return np.nan_to_num(rgb, nan=0.0, posinf=np.finfo(dt).max).astype(np.float64)


@dataclass
class Nbrdf(Lobe):
    """A neural BRDF (Sztrajman et al. 2021, the published ``npy`` layout of asztr/Neural-BRDF), linear RGB.

    ``path`` is the prefix of the six files ``PATH_fc1.npy`` (6, 21), ``_b1`` (21,), ``_fc2`` (21, 21),
    ``_b2`` (21,), ``_fc3`` (21, 3), ``_b3`` (3,). At a direction pair: the Rusinkiewicz angles, phi_d folded into
    [0, pi), x = (sin theta_h, 0, cos theta_h, sin theta_d cos phi_d, sin theta_d sin phi_d, cos theta_d),
    two ReLU layers and f = max(exp(a2 fc3 + b3) - 1, 0) in 1/sr; ``scale`` (the colour) multiplies it.
    """

    type_name: ClassVar[str] = "nbrdf"
    colour_keys: ClassVar[tuple[str, ...]] = ("scale",)
    path: str = ""
    weights: dict[str, Array] | None = None

    def _weights(self) -> dict[str, Array]:
        if self.weights is None:
            self.weights = _nbrdf_weights(self.path)
        return self.weights

    def shape(self, wi: Array, wo: Array) -> Array:  # pragma: no cover - eval is overridden
        raise NotImplementedError

    def eval(self, wi: ArrayLike, wo: ArrayLike, n_channels: int = 0, wavelengths_nm: Array | None = None
             ) -> Array:
        wi, wo = np.broadcast_arrays(np.asarray(wi, dtype=np.float64), np.asarray(wo, dtype=np.float64))
        rgb = nbrdf_forward(nbrdf_features(wi, wo), self._weights())
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        return _rgb_on(np.where(up[..., None], rgb, 0.0) * self.colour.on(3, None), n_channels, "a neural BRDF")

    def params(self) -> dict[str, Any]:
        return {"path": self.path}


LOBE_TYPES: dict[str, type[Lobe]] = {
    "lambert": Lambert,
    "oren_nayar": OrenNayar,
    "ggx": Microfacet,
    "beckmann": Microfacet,
    "phong": Phong,
    "retro": Retro,
    "tabulated": Tabulated,
    "nbrdf": Nbrdf,
}

#: key -> (required, kind) for each lobe type, from the material's schema (reconstruction.schema.material); kind
#: is "colour", "float", "path" or "prefix" (of a file set)
_LOBE_KEYS: dict[str, dict[str, tuple[bool, str]]] = lobe_keys()


def _lobe_from_dict(d: Mapping[str, Any], where: str, base_dir: Path) -> Lobe:
    if not isinstance(d, Mapping):
        raise MaterialError(f"{where}: expected a table, got {d!r}")
    t = d.get("type")
    if t not in _LOBE_KEYS:
        raise MaterialError(f"{where}.type: unknown lobe type {t!r}; expected one of {sorted(_LOBE_KEYS)}")
    spec = _LOBE_KEYS[t]
    allowed = set(spec) | {"type", "wavelengths_nm"}
    unknown = sorted(set(d) - allowed)
    if unknown:
        raise MaterialError(f"{where}: unknown key(s) {unknown} for a {t} lobe; allowed: {sorted(allowed)}")
    missing = [k for k, (req, _) in spec.items() if req and k not in d]
    if missing:
        raise MaterialError(f"{where}: missing key(s) {missing} for a {t} lobe")
    wl = d.get("wavelengths_nm")
    kw: dict[str, Any] = {}
    colour = Colour(np.ones(1))
    for key, (_, kind) in spec.items():
        if key not in d:
            continue
        v = d[key]
        if kind == "colour":
            colour = Colour.parse(v, f"{where}.{key}", wl)
        elif kind == "float":
            if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v):
                raise MaterialError(f"{where}.{key}: expected a finite number, got {v!r}")
            kw[key] = float(v)
        elif kind == "prefix":
            if not isinstance(v, str) or not v:
                raise MaterialError(f"{where}.{key}: expected the prefix of the neural BRDF's npy files, got {v!r}")
            p = Path(v)
            p = p if p.is_absolute() else base_dir / p
            kw[key] = str(p)
            try:
                kw["weights"] = _nbrdf_weights(str(p))
            except MaterialError as e:
                raise MaterialError(f"{where}.{key}: {e}") from None
        else:
            if not isinstance(v, str) or not v:
                raise MaterialError(f"{where}.{key}: expected a file path, got {v!r}")
            p = Path(v)
            p = p if p.is_absolute() else base_dir / p
            if not p.is_file():
                raise MaterialError(f"{where}.{key}: no such file {p}")
            kw[key] = str(p)
    if t in ("ggx", "beckmann"):
        if not kw["alpha"] > 0:
            raise MaterialError(f"{where}.alpha: must be > 0, got {kw['alpha']}")
        if "f0" in kw and not 0.0 <= kw["f0"] <= 1.0:
            raise MaterialError(f"{where}.f0: must lie in [0, 1], got {kw['f0']}")
        return Microfacet(colour=colour, distribution=t, **kw)
    if t in ("phong", "retro") and not kw["exponent"] >= 0:
        raise MaterialError(f"{where}.exponent: must be >= 0, got {kw['exponent']}")
    if t == "oren_nayar" and not 0 <= kw["sigma_deg"] <= 90:
        raise MaterialError(f"{where}.sigma_deg: must lie in [0, 90], got {kw['sigma_deg']}")
    return LOBE_TYPES[t](colour=colour, **kw)


@dataclass
class Material:
    """A named sum of lobes; ``eval`` gives f_r (..., n_channels) in 1/sr."""

    name: str
    lobes: list[Lobe]
    wavelengths_nm: Array | None = None
    n_channels: int = 1

    def __post_init__(self) -> None:
        if not self.lobes:
            raise MaterialError(f"material {self.name!r}: needs at least one lobe")
        spectral = [lb.colour for lb in self.lobes if lb.colour.wavelengths_nm is not None]
        rgb = any(lb.colour.n == 3 and lb.colour.wavelengths_nm is None for lb in self.lobes) or any(
            isinstance(lb, (Tabulated, Nbrdf)) for lb in self.lobes
        )
        if spectral and rgb:
            raise MaterialError(f"material {self.name!r}: cannot mix RGB and spectral colours")
        if spectral:
            if self.wavelengths_nm is None:
                self.wavelengths_nm = spectral[0].wavelengths_nm
            self.n_channels = int(np.asarray(self.wavelengths_nm).size)
        else:
            self.n_channels = 3 if rgb else 1

    def eval(self, wi: ArrayLike, wo: ArrayLike) -> Array:
        """f_r (..., n_channels) in 1/sr for unit directions (..., 3); 0 below the horizon."""
        wi = np.asarray(wi, dtype=np.float64)
        wo = np.asarray(wo, dtype=np.float64)
        out = np.zeros(np.broadcast_shapes(wi.shape, wo.shape)[:-1] + (self.n_channels,))
        for lobe in self.lobes:  # a handful of lobes, each vectorised over all directions
            out += lobe.eval(wi, wo, self.n_channels, self.wavelengths_nm)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {"name": self.name, "lobes": [lb.to_dict() for lb in self.lobes]}

    @classmethod
    def from_dict(cls, d: Mapping[str, Any], base_dir: Path | str = ".", source: str = "[material]"
                  ) -> Material:
        """Build from the ``[material]`` table: ``name`` and a list ``lobes`` of tables with ``type``."""
        if not isinstance(d, Mapping):
            raise MaterialError(f"{source}: expected a table")
        unknown = sorted(set(d) - {"name", "lobes"})
        if unknown:
            raise MaterialError(f"{source}: unknown key(s) {unknown}; allowed: name, lobes")
        name = d.get("name", "material")
        if not isinstance(name, str):
            raise MaterialError(f"{source}.name: expected a string, got {name!r}")
        lobes = d.get("lobes")
        if not isinstance(lobes, list) or not lobes:
            raise MaterialError(f"{source}.lobes: expected at least one [[material.lobes]] table")
        base = Path(base_dir)
        return cls(name, [_lobe_from_dict(lb, f"{source}.lobes[{i}]", base) for i, lb in enumerate(lobes)])

    @classmethod
    def from_toml(cls, path: str | Path) -> Material:
        """Read the ``[material]`` table of a TOML file (a material file or a bench config)."""
        p = Path(path)
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except FileNotFoundError:
            raise MaterialError(f"{p}: no such file") from None
        except tomllib.TOMLDecodeError as e:
            raise MaterialError(f"{p}: invalid TOML: {e}") from None
        if "material" not in data:
            raise MaterialError(f"{p}: no [material] table")
        return cls.from_dict(data["material"], p.parent, source=f"{p}: [material]")
