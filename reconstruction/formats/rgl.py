"""RGL ``.bsdf`` files: a reconstruction on the adaptive parameterization of Dupuy & Jakob (2018), as Mitsuba 3's
``measured`` plugin reads them (isotropic, RGB).

The file is a *tensor file*: the 12 bytes ``tensor_file\\0``, a version (2 bytes: 1, 0), the number of fields
(uint32), then per field its name (uint16 length + UTF-8), rank (uint16), dtype code (uint8: 1 uint8 ... 10 float32,
11 float64), the byte offset of its data (uint64) and its shape (rank x uint64); then the data, each field
C-contiguous, little-endian, at an 8-byte aligned offset. The fields of a measured material:

* ``description`` (uint8 text) and ``jacobian`` (uint8 [1]; 1: the stored values are divided by the microfacet
  factor D(m) / (4 sigma(wi)), which the renderer multiplies back);
* ``theta_i`` (float32 [n_i], radians) and ``phi_i`` (float32 [1]: isotropic, the azimuth of wi is irrelevant);
* ``ndf`` (float32 [2, n_ndf]): the normal distribution D(theta_m) in 1/sr, normalised so that the integral of
  D cos theta_m over the hemisphere is 1, at theta_m = u^2 pi/2, u = 0 .. 1 in n_ndf steps (two identical rows:
  isotropic), *retrieved from the reconstruction* by the power iteration of Dupuy et al. (2015) on its
  back-scattering f(w, w): D(w) is proportional to f(w, w) cos theta sigma(w); 10 % of the uniform NDF 1/pi is
  mixed in (:data:`UNIFORM_SHARE`) so the sample grid also covers directions far from a sharp peak;
* ``sigma`` (float32 [2, n_ndf]): its projected area sigma(w) = integral of D(m) max(0, m . w) dm, same grid;
* ``vndf`` (float32 [1, n_i, n_v, n_v]): per incidence the visible-normal density D(m) max(0, m . wi) in the unit
  square u = (sqrt(theta_m / (pi/2)), (phi_m - phi_i + pi) / 2 pi), times the Jacobian of that square (rows:
  azimuth, columns: elevation); the renderer builds a continuous marginal/conditional warp from it;
* ``luminance`` (float32 [1, n_i, n_s, n_s]): the luminance of the stored values over the *sample* square (the
  warp's input), which the renderer samples first, so f cos theta_o is importance sampled;
* ``rgb`` (float32 [1, n_i, 3, n_s, n_s]): linear-sRGB f_r cos theta_o 4 sigma(wi) / D(m) at the nodes of the
  sample square, i.e. at the half vectors m the VNDF warp maps them to, wo = 2 (wi . m) m - wi. The renderer
  inverts the warp for (wi, wo), interpolates bilinearly (and linearly in theta_i) and multiplies by
  D(m) / (4 sigma(wi)).

This writer is our own implementation of that layout (read from the paper and Mitsuba 3's ``measured.cpp``,
``distr_2d.h`` and ``tensor.cpp``); :class:`RGLTable` evaluates a file the way the renderer does, with numpy.
Resolution is the price of a compact file: n_s x n_s values per incidence, placed by the VNDF, so a peak is
resolved as finely as its visible normals are spread, but a feature off the microfacet structure (a narrow retro
lobe, a second sharp peak) only as finely as the grid falls there.
"""

from __future__ import annotations

import math
import struct
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.atomic import atomic_open
from reconstruction.base import ReconstructionError

Array = NDArray[np.float64]
BRDF = Callable[[Array, Array], ArrayLike]

__all__ = ["TENSOR_MAGIC", "RGLError", "Resolution", "DEFAULT_RESOLUTION", "write_tensor_file",
           "read_tensor_file", "retrieve_ndf", "projected_area", "build_fields", "write", "RGLTable",
           "warp_sample", "warp_grid", "warp_invert"]

TENSOR_MAGIC = b"tensor_file\x00"
_DTYPES: dict[np.dtype[Any], int] = {np.dtype(t): c for t, c in (
    (np.uint8, 1), (np.int8, 2), (np.uint16, 3), (np.int16, 4), (np.uint32, 5), (np.int32, 6), (np.uint64, 7),
    (np.int64, 8), (np.float16, 9), (np.float32, 10), (np.float64, 11))}
_CODES = {c: t for t, c in _DTYPES.items()}
_LUMA = np.array([0.2126, 0.7152, 0.0722])  # linear sRGB -> luminance Y
_ALIGN = 8
#: share of the uniform NDF (1/pi) mixed into the retrieved one: on chrome (a sharp peak, almost no diffuse
#: reflection) the median relative error over the hemisphere falls from 58 % to 1.2 %, near the peak it stays 2 %
UNIFORM_SHARE = 0.1


class RGLError(ReconstructionError):
    """A tensor file cannot be read or a table cannot be built; the message names the file and what is wrong."""


@dataclass(frozen=True)
class Resolution:
    """Table sizes: incidences (uniform in theta_i from 0 to ``theta_i_max_deg``), sample-square nodes per side,
    VNDF nodes per side, NDF nodes."""

    n_theta_i: int = 30
    n_sample: int = 64
    n_vndf: int = 64
    n_ndf: int = 128
    theta_i_max_deg: float = 87.0

    def __post_init__(self) -> None:
        if min(self.n_theta_i, self.n_sample, self.n_vndf, self.n_ndf) < 2:
            raise RGLError(f"RGL resolution {self}: every size must be >= 2")
        if not 0.0 < self.theta_i_max_deg < 90.0:
            raise RGLError(f"RGL resolution: theta_i_max_deg must lie in (0, 90), got {self.theta_i_max_deg}")


DEFAULT_RESOLUTION = Resolution()


# --- tensor files ----------------------------------------------------------------------------------------


def write_tensor_file(path: str | Path, fields: Mapping[str, ArrayLike | str]) -> int:
    """Write ``fields`` (name -> array, or str stored as uint8 text) as a tensor file, atomically; returns bytes."""
    arrays: list[tuple[bytes, NDArray[Any]]] = []
    for name, value in fields.items():
        a = (np.frombuffer(value.encode("utf-8"), dtype=np.uint8) if isinstance(value, str)
             else np.ascontiguousarray(value))
        if a.dtype.newbyteorder("<") not in _DTYPES:
            raise RGLError(f"{path}: field {name!r} has unsupported dtype {a.dtype}")
        arrays.append((name.encode("utf-8"), a.astype(a.dtype.newbyteorder("<"), copy=False)))
    header_size = len(TENSOR_MAGIC) + 2 + 4 + sum(2 + len(n) + 2 + 1 + 8 + 8 * a.ndim for n, a in arrays)
    offsets, pos = [], header_size
    for _, a in arrays:
        pos = -(-pos // _ALIGN) * _ALIGN
        offsets.append(pos)
        pos += a.nbytes
    out = bytearray(TENSOR_MAGIC + struct.pack("<BBI", 1, 0, len(arrays)))
    for (name, a), off in zip(arrays, offsets, strict=True):
        out += struct.pack("<H", len(name)) + name + struct.pack("<HBQ", a.ndim, _DTYPES[a.dtype.newbyteorder("<")],
                                                                 off)
        out += struct.pack(f"<{a.ndim}Q", *a.shape)
    for (_, a), off in zip(arrays, offsets, strict=True):
        out += bytes(off - len(out)) + a.tobytes()
    with atomic_open(path, "wb") as fh:
        fh.write(out)
    return len(out)


def read_tensor_file(path: str | Path) -> dict[str, NDArray[Any]]:
    """Read a tensor file into name -> array (``description`` stays a uint8 array); :class:`RGLError` if bad."""
    path = Path(path)
    try:
        data = path.read_bytes()
    except FileNotFoundError:
        raise RGLError(f"{path}: no such file") from None
    if len(data) < 18 or data[:12] != TENSOR_MAGIC:
        raise RGLError(f"{path}: not a tensor file (expected the header 'tensor_file\\0')")
    major, minor, n = struct.unpack_from("<BBI", data, 12)
    if (major, minor) != (1, 0):
        raise RGLError(f"{path}: tensor file version {major}.{minor}, expected 1.0")
    pos, out = 18, {}
    try:
        for _ in range(n):
            (ln,) = struct.unpack_from("<H", data, pos)
            name = data[pos + 2:pos + 2 + ln].decode("utf-8")
            pos += 2 + ln
            ndim, code, off = struct.unpack_from("<HBQ", data, pos)
            pos += 11
            shape = struct.unpack_from(f"<{ndim}Q", data, pos)
            pos += 8 * ndim
            if code not in _CODES:
                raise RGLError(f"{path}: field {name!r} has unknown dtype code {code}")
            dt = _CODES[code]
            count = int(np.prod(shape, dtype=np.int64))
            if off + count * dt.itemsize > len(data):
                raise RGLError(f"{path}: field {name!r} runs past the end of the file (truncated?)")
            out[name] = np.frombuffer(data, dtype=dt, count=count, offset=off).reshape(shape)
    except struct.error:
        raise RGLError(f"{path}: the field table is truncated") from None
    return out


# --- parameterization ------------------------------------------------------------------------------------


def u2theta(u: ArrayLike) -> Array:
    """Elevation (radians) of the unit coordinate u: theta = u^2 pi / 2."""
    return np.square(np.asarray(u, dtype=np.float64)) * (np.pi / 2)


def theta2u(theta: ArrayLike) -> Array:
    """Unit coordinate of an elevation (radians): u = sqrt(theta / (pi / 2))."""
    return np.sqrt(np.clip(np.asarray(theta, dtype=np.float64), 0.0, None) * (2 / np.pi))


def _interp_nodes(values: Array, u: ArrayLike) -> Array:
    """Linear interpolation of node ``values`` (n,) at u in [0, 1] (nodes at k / (n - 1)), as the renderer's
    bilinear lookup does along one axis."""
    n = values.shape[-1]
    x = np.clip(np.asarray(u, dtype=np.float64), 0.0, 1.0) * (n - 1)
    k = np.minimum(x.astype(np.int64), n - 2)
    t = x - k
    return values[k] * (1.0 - t) + values[k + 1] * t


def _phi_integral(cos_m: Array, sin_m: Array, cos_w: float | Array, sin_w: float | Array) -> Array:
    """Integral over phi in [0, 2 pi) of max(0, cos_m cos_w + sin_m sin_w cos phi) (closed form)."""
    a = cos_m * cos_w
    b = sin_m * sin_w
    full = np.where(a > 0, 2 * np.pi * a, 0.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        p0 = np.arccos(np.clip(-a / np.where(b > 0, b, 1.0), -1.0, 1.0))
        part = 2.0 * (a * p0 + b * np.sin(p0))
    return np.where(b > np.abs(a), part, full)


def projected_area(d_nodes: Array, theta_w: ArrayLike, n_sub: int = 8) -> Array:
    """sigma(w) = integral of D(m) max(0, m . w) dm for the isotropic NDF given at u nodes ``d_nodes`` (linear in u
    between them), at elevations ``theta_w`` (radians); D in 1/sr, sigma dimensionless."""
    n = d_nodes.size
    m = (n - 1) * n_sub + 1
    u = np.linspace(0.0, 1.0, m)
    th = u2theta(u)
    d = _interp_nodes(d_nodes, u)
    w = np.full(m, 1.0 / (m - 1))
    w[[0, -1]] *= 0.5
    tw = np.atleast_1d(np.asarray(theta_w, dtype=np.float64))
    g = _phi_integral(np.cos(th)[None], np.sin(th)[None], np.cos(tw)[:, None], np.sin(tw)[:, None])
    # dm = sin(theta) dtheta dphi, dtheta = pi u du
    return (g * (d * np.sin(th) * np.pi * u * w)[None]).sum(axis=1)


def retrieve_ndf(f: BRDF, n: int = DEFAULT_RESOLUTION.n_ndf, iterations: int = 8) -> Array:
    """The NDF (n,) at u nodes k / (n - 1), 1/sr, from the back-scattering of ``f`` by power iteration.

    For a microfacet BRDF, f(w, w) = F D(w) / (4 cos theta sigma(w)) (shadowing and masking coincide at back
    scattering), so D is the fixed point of D = c f(w, w) cos theta sigma_D(w); c normalises the integral of
    D cos theta_m to 1 (sigma(normal) = 1). Any BRDF gives a valid, positive parameterization this way.
    """
    th = np.minimum(u2theta(np.linspace(0.0, 1.0, n)), np.radians(89.9))
    w = np.stack([np.sin(th), np.zeros_like(th), np.cos(th)], axis=-1)
    back = np.asarray(f(w, w), dtype=np.float64).reshape(n, -1)
    y = back @ _LUMA if back.shape[1] == 3 else back.mean(axis=1)
    y = np.maximum(np.nan_to_num(y, nan=0.0, posinf=0.0), 0.0)
    if not np.any(y > 0):
        y = np.ones(n)  # no back-scattering at all: a uniform parameterization
    y = np.maximum(y, 1e-9 * y.max())
    d = y * np.cos(th)
    for _ in range(iterations):  # converges in a few steps (Dupuy et al. 2015)
        d = d / projected_area(d, 0.0)[0]
        d = y * np.cos(th) * projected_area(d, th)
    d = d / projected_area(d, 0.0)[0]
    return np.maximum(d, 1e-12 * d.max())


# --- the continuous marginal/conditional warp of a bilinear density -----------------------------------------


def _solve_segment(r: Array, c0: Array, c1: Array, width: float) -> Array:
    """t in [0, 1] with width (c0 t + (c1 - c0) t^2 / 2) = r (the CDF of a linear density across one patch)."""
    a = 0.5 * (c1 - c0) * width
    b = c0 * width
    disc = np.sqrt(np.maximum(b * b + 4.0 * a * r, 0.0))
    den = b + disc
    with np.errstate(divide="ignore", invalid="ignore"):
        t = np.where(den > 0, 2.0 * r / np.where(den > 0, den, 1.0), 0.0)
    return np.clip(t, 0.0, 1.0)


def _cumulative(rows: Array) -> Array:
    """Cumulative trapezoid integrals along the last axis of node values on [0, 1] (first entry 0)."""
    w = 1.0 / (rows.shape[-1] - 1)
    seg = 0.5 * (rows[..., 1:] + rows[..., :-1]) * w
    return np.concatenate([np.zeros(rows.shape[:-1] + (1,)), np.cumsum(seg, axis=-1)], axis=-1)


def _find(cdf: Array, target: Array) -> Array:
    """Index k of the interval of ``cdf`` (..., n) holding ``target`` (...), clipped to 0 .. n - 2."""
    k = np.sum(cdf[..., 1:-1] < target[..., None], axis=-1)
    return np.clip(k, 0, cdf.shape[-1] - 2)


def warp_sample(density: Array, s: Array) -> Array:
    """Map points ``s`` (S, N, 2) of the unit square to the density's domain: (S, N, 2) in [0, 1]^2.

    ``density`` (S, H, W): bilinear node values, rows y (marginal), columns x (conditional given y); this is the
    continuous marginal/conditional inversion the renderer performs (Mitsuba's Marginal2D, continuous variant).
    """
    dens = np.asarray(density, dtype=np.float64)
    n_s, h, w = dens.shape
    row_int = _cumulative(dens)[..., -1]  # (S, H) integral of each row over x
    marg = _cumulative(row_int)  # (S, H)
    sy = np.clip(s[..., 1], 0.0, 1.0) * marg[:, -1:]
    j = _find(marg[:, None, :], sy)  # (S, N)
    take = lambda a, idx: np.take_along_axis(a, idx, axis=1)  # noqa: E731
    r0, r1 = take(row_int, j), take(row_int, j + 1)
    ty = _solve_segment(sy - take(marg, j), r0, r1, 1.0 / (h - 1))
    rows0 = np.take_along_axis(dens, j[..., None], axis=1)  # (S, N, W)
    rows1 = np.take_along_axis(dens, (j + 1)[..., None], axis=1)
    cond = rows0 * (1.0 - ty[..., None]) + rows1 * ty[..., None]
    ccdf = _cumulative(cond)
    sx = np.clip(s[..., 0], 0.0, 1.0) * ccdf[..., -1]
    k = _find(ccdf, sx)
    c0 = np.take_along_axis(cond, k[..., None], axis=-1)[..., 0]
    c1 = np.take_along_axis(cond, (k + 1)[..., None], axis=-1)[..., 0]
    tx = _solve_segment(sx - np.take_along_axis(ccdf, k[..., None], axis=-1)[..., 0], c0, c1, 1.0 / (w - 1))
    return np.stack([(k + tx) / (w - 1), (j + ty) / (h - 1)], axis=-1)


def warp_grid(density: Array, n: int) -> Array:
    """:func:`warp_sample` of the n x n nodes of the unit square (rows: y), faster: each row of nodes shares its
    marginal inversion. Returns (S, n, n, 2)."""
    dens = np.asarray(density, dtype=np.float64)
    n_s, h, w = dens.shape
    ss = np.linspace(0.0, 1.0, n)
    row_int = _cumulative(dens)[..., -1]  # (S, H)
    marg = _cumulative(row_int)
    sy = ss[None, :] * marg[:, -1:]  # (S, n)
    j = _find(marg[:, None, :], sy)
    take = lambda a, idx: np.take_along_axis(a, idx, axis=1)  # noqa: E731
    ty = _solve_segment(sy - take(marg, j), take(row_int, j), take(row_int, j + 1), 1.0 / (h - 1))
    cond = (np.take_along_axis(dens, j[..., None], axis=1) * (1.0 - ty[..., None])
            + np.take_along_axis(dens, (j + 1)[..., None], axis=1) * ty[..., None])  # (S, n, W)
    ccdf = _cumulative(cond)
    sx = ss[None, None, :] * ccdf[..., -1:]  # (S, n, n)
    k = np.clip(np.sum(ccdf[..., None, 1:-1] < sx[..., None], axis=-1), 0, w - 2)
    c0 = np.take_along_axis(cond, k, axis=-1)
    c1 = np.take_along_axis(cond, k + 1, axis=-1)
    tx = _solve_segment(sx - np.take_along_axis(ccdf, k, axis=-1), c0, c1, 1.0 / (w - 1))
    y = np.broadcast_to(((j + ty) / (h - 1))[..., None], k.shape)
    return np.stack([(k + tx) / (w - 1), y], axis=-1)


def warp_invert(density: Array, u: Array) -> Array:
    """Inverse of :func:`warp_sample`: points ``u`` (N, 2) of the domain -> the unit square (N, 2).

    ``density`` (N, H, W): per point its own (e.g. interpolated across incidences) node values.
    """
    dens = np.asarray(density, dtype=np.float64)
    _, h, w = dens.shape
    row_int = _cumulative(dens)[..., -1]  # (N, H)
    marg = _cumulative(row_int)
    y = np.clip(u[:, 1], 0.0, 1.0) * (h - 1)
    j = np.minimum(y.astype(np.int64), h - 2)
    ty = y - j
    idx = np.arange(dens.shape[0])
    r0, r1 = row_int[idx, j], row_int[idx, j + 1]
    hy = 1.0 / (h - 1)
    sy = (marg[idx, j] + hy * (r0 * ty + 0.5 * (r1 - r0) * ty * ty)) / np.maximum(marg[:, -1], 1e-300)
    cond = dens[idx, j] * (1.0 - ty[:, None]) + dens[idx, j + 1] * ty[:, None]  # (N, W)
    ccdf = _cumulative(cond)
    x = np.clip(u[:, 0], 0.0, 1.0) * (w - 1)
    k = np.minimum(x.astype(np.int64), w - 2)
    tx = x - k
    c0, c1 = cond[idx, k], cond[idx, k + 1]
    hx = 1.0 / (w - 1)
    sx = (ccdf[idx, k] + hx * (c0 * tx + 0.5 * (c1 - c0) * tx * tx)) / np.maximum(ccdf[:, -1], 1e-300)
    return np.stack([sx, sy], axis=-1)


# --- building the tables ---------------------------------------------------------------------------------


def _half_vector(u: Array) -> Array:
    """Half vectors (..., 3) of unit coordinates u (..., 2) = (elevation, azimuth relative to phi_i = 0)."""
    th = u2theta(u[..., 0])
    ph = (2.0 * u[..., 1] - 1.0) * np.pi
    st = np.sin(th)
    return np.stack([st * np.cos(ph), st * np.sin(ph), np.cos(th)], axis=-1)


def _vndf_density(d_nodes: Array, theta_i: Array, n: int) -> Array:
    """(n_i, n, n): D(m) max(0, m . wi) times the unit-square Jacobian 2 pi^2 u sin theta_m, rows = azimuth."""
    uu = np.linspace(0.0, 1.0, n)
    grid = np.stack(np.meshgrid(uu, uu, indexing="xy"), axis=-1)  # [v, u, 2] = (u, v)
    m = _half_vector(grid)
    th = u2theta(uu)
    d = _interp_nodes(d_nodes, uu)
    jac = 2.0 * np.pi ** 2 * uu * np.sin(th)
    wi = np.stack([np.sin(theta_i), np.zeros_like(theta_i), np.cos(theta_i)], axis=-1)  # (n_i, 3)
    dot = np.maximum(np.einsum("vuk,ik->ivu", m, wi), 0.0)
    return dot * (d * jac)[None, None, :]


def build_fields(f: BRDF, *, resolution: Resolution = DEFAULT_RESOLUTION, description: str = "gonio-brdf"
                 ) -> dict[str, Any]:
    """The fields of a measured-material tensor file for the BRDF ``f(wi, wo) -> (N, 1 | 3)`` (1/sr, linear RGB
    or grey), plus ``_stats`` (not written): the nodes' range and how many lie below the horizon."""
    r = resolution
    # a share of the uniform NDF 1/pi keeps part of the sample grid on the whole hemisphere, so a BRDF whose
    # back-scattering is one sharp peak (a metal) is still resolved away from it
    d_nodes = (1.0 - UNIFORM_SHARE) * retrieve_ndf(f, r.n_ndf) + UNIFORM_SHARE / np.pi
    u_nodes = np.linspace(0.0, 1.0, r.n_ndf)
    sigma_nodes = projected_area(d_nodes, u2theta(u_nodes))
    theta_i = np.linspace(0.0, math.radians(r.theta_i_max_deg), r.n_theta_i)
    vndf = _vndf_density(d_nodes, theta_i, r.n_vndf)
    u = warp_grid(vndf, r.n_sample).reshape(r.n_theta_i, -1, 2)  # (n_i, n_s^2, 2), rows: y (azimuth)
    m = _half_vector(u)
    wi = np.stack([np.sin(theta_i), np.zeros_like(theta_i), np.cos(theta_i)], axis=-1)[:, None, :]
    wi = np.broadcast_to(wi, m.shape)
    wo = 2.0 * np.sum(wi * m, axis=-1, keepdims=True) * m - wi
    cos_o = wo[..., 2]
    wo_eval = wo.copy()
    wo_eval[..., 2] = np.maximum(cos_o, 1e-6)
    wo_eval /= np.linalg.norm(wo_eval, axis=-1, keepdims=True)
    wi_eval = wi.copy()
    wi_eval[..., 2] = np.maximum(wi_eval[..., 2], 1e-6)
    vals = np.asarray(f(wi_eval.reshape(-1, 3), wo_eval.reshape(-1, 3)), dtype=np.float64)
    vals = vals.reshape(r.n_theta_i, r.n_sample * r.n_sample, -1)
    if vals.shape[-1] == 1:
        vals = np.repeat(vals, 3, axis=-1)
    if vals.shape[-1] != 3:
        raise RGLError(f"RGL export needs 1 (grey) or 3 (RGB) channels, got {vals.shape[-1]}")
    vals = np.maximum(np.nan_to_num(vals, nan=0.0, posinf=0.0), 0.0)
    sig_i = _interp_nodes(sigma_nodes, theta2u(theta_i))[:, None]
    d_m = _interp_nodes(d_nodes, u[..., 0])
    scale = np.maximum(cos_o, 0.0) * 4.0 * sig_i / d_m
    stored = vals * scale[..., None]  # f cos theta_o 4 sigma / D
    lum = stored @ _LUMA
    lum = lum + 1e-4 * np.maximum(lum.max(axis=1, keepdims=True), 1e-30)  # every slice can be sampled
    n_s = r.n_sample
    rgb = stored.reshape(r.n_theta_i, n_s, n_s, 3).transpose(0, 3, 1, 2)
    fields: dict[str, Any] = {
        "description": description,
        "jacobian": np.array([1], dtype=np.uint8),
        "theta_i": theta_i.astype(np.float32),
        "phi_i": np.zeros(1, dtype=np.float32),
        "ndf": np.repeat(d_nodes[None], 2, axis=0).astype(np.float32),
        "sigma": np.repeat(sigma_nodes[None], 2, axis=0).astype(np.float32),
        "vndf": vndf[None].astype(np.float32),
        "luminance": lum.reshape(1, r.n_theta_i, n_s, n_s).astype(np.float32),
        "rgb": rgb[None].astype(np.float32),
    }
    fields["_stats"] = {"below_horizon_nodes": float(np.mean(cos_o <= 0)), "max_stored": float(stored.max())}
    return fields


def write(path: str | Path, f: BRDF, *, resolution: Resolution = DEFAULT_RESOLUTION,
          description: str = "gonio-brdf") -> dict[str, Any]:
    """Write the BRDF ``f`` as an RGL ``.bsdf`` tensor file (atomically); returns what was written."""
    fields = build_fields(f, resolution=resolution, description=description)
    stats = fields.pop("_stats")
    size = write_tensor_file(path, fields)
    return {"rgl": str(path), "rgl_bytes": size, "resolution": {
        "theta_i": int(resolution.n_theta_i), "theta_i_max_deg": resolution.theta_i_max_deg,
        "sample": [resolution.n_sample, resolution.n_sample], "vndf": [resolution.n_vndf, resolution.n_vndf],
        "ndf": resolution.n_ndf}, "jacobian": 1, "channels": "linear sRGB", **stats}


# --- evaluation as the renderer does it --------------------------------------------------------------------


def _bilinear_at(table: Array, node: NDArray[np.int64], pos: Array) -> Array:
    """Bilinear interpolation of ``table[node]`` (table (n_nodes, C, H, W) of node values; node (N,)) at ``pos``
    (N, 2) = (x, y) in [0, 1]^2, reading only the four cells of each point (no (N, C, H, W) copy): (N, C)."""
    h, w = table.shape[-2:]
    x = np.clip(pos[:, 0], 0.0, 1.0) * (w - 1)
    y = np.clip(pos[:, 1], 0.0, 1.0) * (h - 1)
    k = np.minimum(x.astype(np.int64), w - 2)
    j = np.minimum(y.astype(np.int64), h - 2)
    tx, ty = (x - k)[:, None], (y - j)[:, None]
    g = np.moveaxis(table, 1, -1)  # (n_nodes, H, W, C): a view
    return ((1 - tx) * (1 - ty) * g[node, j, k] + tx * (1 - ty) * g[node, j, k + 1]
            + (1 - tx) * ty * g[node, j + 1, k] + tx * ty * g[node, j + 1, k + 1])


class RGLTable:
    """An isotropic measured-material file, evaluated with numpy as Mitsuba 3's ``measured`` plugin does: RGB
    (field ``rgb``, our writer and the database's ``*_rgb.bsdf``) or spectral (fields ``spectra`` (n_phi, n_i, W,
    n, n) and ``wavelengths`` (W,) in nm, the database's spectral files; ``channels`` are then ``"<nm>nm"``)."""

    def __init__(self, fields: Mapping[str, NDArray[Any]], source: str = "<memory>") -> None:
        spectral = "rgb" not in fields and "spectra" in fields
        need = ("theta_i", "phi_i", "ndf", "sigma", "vndf", "jacobian") + (("spectra", "wavelengths") if spectral
                                                                            else ("rgb",))
        missing = [k for k in need if k not in fields]
        if missing:
            raise RGLError(f"{source}: not a measured material: no field(s) {', '.join(missing)}")
        values = np.asarray(fields["spectra" if spectral else "rgb"])
        if values.ndim != 5 or values.shape[1] != np.asarray(fields["theta_i"]).size:
            raise RGLError(f"{source}: field {'spectra' if spectral else 'rgb'} has shape {values.shape}; expected "
                           f"(phi_i, theta_i = {np.asarray(fields['theta_i']).size}, channels, n, n)")
        if fields["phi_i"].shape[0] > 2:
            raise RGLError(f"{source}: anisotropic ({fields['phi_i'].shape[0]} phi_i); only isotropic files are "
                           f"evaluated")
        self.source = source
        self.theta_i = np.asarray(fields["theta_i"], dtype=np.float64)
        self.ndf = np.asarray(fields["ndf"], dtype=np.float64)[0]
        self.sigma = np.asarray(fields["sigma"], dtype=np.float64)[0]
        v = np.asarray(fields["vndf"], dtype=np.float64)[0]
        self.vndf = v / np.maximum(_cumulative(_cumulative(v)[..., -1])[:, -1], 1e-300)[:, None, None]
        self._cum: tuple[Array, Array, Array] | None = None  # the vndf's cumulative integrals, on first eval
        self.rgb = values.astype(np.float64)[0]  # (n_i, C, n_s, n_s): 3 (RGB) or one per wavelength
        self.jacobian = bool(np.asarray(fields["jacobian"])[0])
        self.method = "rgl"
        self.wavelengths_nm = np.asarray(fields["wavelengths"], dtype=np.float64).ravel() if spectral else None
        self.channels = ([f"{w:g}nm" for w in self.wavelengths_nm] if self.wavelengths_nm is not None
                         else ["R", "G", "B"])

    @classmethod
    def read(cls, path: str | Path) -> RGLTable:
        return cls(read_tensor_file(path), str(path))

    def _weights(self, theta: Array) -> tuple[Array, Array]:
        n = self.theta_i.size
        if n == 1:
            return np.zeros(theta.shape, dtype=np.int64), np.zeros(theta.shape)
        k = np.clip(np.searchsorted(self.theta_i, theta, side="left") - 1, 0, n - 2)
        t = np.clip((theta - self.theta_i[k]) / (self.theta_i[k + 1] - self.theta_i[k]), 0.0, 1.0)
        return k, t

    def _warp_invert(self, k: NDArray[np.int64], k1: NDArray[np.int64], t: Array, u: Array) -> Array:
        """:func:`warp_invert` of the density ``vndf[k] (1 - t) + vndf[k1] t`` of each point at ``u`` (N, 2),
        without building the N interpolated grids: the cumulative integrals are linear in the density, so they are
        those of the incidence nodes (computed once per table), interpolated the same way; only the cells the
        inversion reads are gathered (O(N) instead of O(N H W) time and memory)."""
        if self._cum is None:
            cx = _cumulative(self.vndf)  # (n_i, H, W) along x
            row_int = cx[..., -1]  # (n_i, H)
            self._cum = (cx, row_int, _cumulative(row_int))
        cx, row_int, marg = self._cum
        _, h, w = self.vndf.shape
        a, b = (1.0 - t), t
        y = np.clip(u[:, 1], 0.0, 1.0) * (h - 1)
        j = np.minimum(y.astype(np.int64), h - 2)
        ty = y - j
        r0 = row_int[k, j] * a + row_int[k1, j] * b
        r1 = row_int[k, j + 1] * a + row_int[k1, j + 1] * b
        total_y = marg[k, -1] * a + marg[k1, -1] * b
        hy = 1.0 / (h - 1)
        sy = (marg[k, j] * a + marg[k1, j] * b + hy * (r0 * ty + 0.5 * (r1 - r0) * ty * ty)) / np.maximum(total_y,
                                                                                                      1e-300)
        x = np.clip(u[:, 0], 0.0, 1.0) * (w - 1)
        kx = np.minimum(x.astype(np.int64), w - 2)
        tx = x - kx

        def cond(grid: Array, col: NDArray[np.int64] | int) -> Array:
            """The conditional row (rows j and j + 1 mixed by ty, the nodes by t) of ``grid`` at column ``col``."""
            return ((grid[k, j, col] * a + grid[k1, j, col] * b) * (1.0 - ty)
                    + (grid[k, j + 1, col] * a + grid[k1, j + 1, col] * b) * ty)

        c0, c1 = cond(self.vndf, kx), cond(self.vndf, kx + 1)
        hx = 1.0 / (w - 1)
        sx = (cond(cx, kx) + hx * (c0 * tx + 0.5 * (c1 - c0) * tx * tx)) / np.maximum(cond(cx, -1), 1e-300)
        return np.stack([sx, sy], axis=-1)

    def eval(self, wi: ArrayLike, wo: ArrayLike) -> Array:
        """f_r (N, C) in 1/sr (the renderer's value divided by cos theta_o); 0 below the horizon."""
        wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        h = wi + wo
        m = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        th_i = np.arccos(np.clip(wi[:, 2], -1, 1))
        th_m = np.arccos(np.clip(m[:, 2], -1, 1))
        phi_rel = np.arctan2(m[:, 1], m[:, 0]) - np.arctan2(wi[:, 1], wi[:, 0])
        u_m = np.stack([theta2u(th_m), np.mod((phi_rel + np.pi) / (2 * np.pi), 1.0)], axis=-1)
        k, t = self._weights(th_i)
        k1 = k + 1 if self.theta_i.size > 1 else k
        s = self._warp_invert(k, k1, t, u_m)
        spec = _bilinear_at(self.rgb, k, s) * (1 - t)[:, None] + _bilinear_at(self.rgb, k1, s) * t[:, None]
        if self.jacobian:
            spec = spec * (_interp_nodes(self.ndf, u_m[:, 0]) / (4.0 * _interp_nodes(self.sigma, theta2u(th_i))
                                                                   ))[:, None]
        return np.where(up[:, None], spec / np.maximum(wo[:, 2:3], 1e-12), 0.0)
