"""A sphere rendered with a BRDF under a sky-and-ground environment, suns and point lights: the project's renderer
(the HTML report's spheres, the preview's point light, and the image metrics of :mod:`reconstruction.core.metrics`).

Scene. World frame x right, y up, z towards the camera; an orthographic camera looking along -z at a unit
sphere at the origin, whose radius is ``radius`` of the half frame (1 fills the frame). Every pixel centre inside
the sphere's disc sees the surface point whose normal n is that point's position; the view direction is
v = (0, 0, 1) and the view angle is theta_o = arccos(n_z).

Shading frame. Per pixel a local frame with z = n and x = the tangent towards the view (v minus its normal
component; any tangent at the disc's centre), so the view is always wo = (sin theta_o, 0, cos theta_o): the
BRDF ``f(wi, wo) -> (..., C)`` (1/sr) is called with unit vectors in that frame (isotropic BRDFs, as every method
here gives, do not depend on the choice of tangent).

Lighting (:class:`Lighting`): radiance L_o = integral of f(wi, wo) L_env(wi) cos theta_i d omega_i over the local
hemisphere, plus f(s, wo) E cos theta_s for each sun (a distant light of irradiance E on a surface facing it,
direction s towards it) and f(l, wo) I cos theta_l / d^2 for each point light (intensity I at distance d).
:class:`SkyGround` is the environment: a sky brighter towards the zenith over a dim ground, its horizon blended
over +-10 deg of elevation (a function of the world elevation only).

Quadrature of the environment: the same fixed, deterministic set of directions in every pixel's local frame (so
the image is the same at every call and free of noise), combined by the balance heuristic of multiple importance
sampling: cosine-weighted directions (a Fibonacci lattice mapped to the hemisphere; diffuse light) and, for
every GGX roughness of :attr:`Quadrature.alphas`, directions reflected about GGX visible normals of ``wo``
(Heitz 2018, "Sampling the GGX distribution of visible normals"; a lattice of the same kind), which follow a
specular lobe at any view angle, the grazing views of the sphere's rim included. Each direction's weight is
L_env cos / (sum over strategies of n_k p_k), so sharp and broad lobes are both integrated without bias towards
either. Every direction is paired with its mirror image in the plane of wo (local y -> -y), where an isotropic f
has the same value: the environment is read at both for one evaluation of f (antithetic pairs; an anisotropic f
would be averaged with its mirror image). The default :class:`Quadrature` (275 directions) is within about 1 % RMS
(3 % at worst) of a dense integral over the pixels seen at up to 80 deg, for lobes from GGX alpha 0.005 to
Lambert; tests/test_render.py checks pixels against a brute-force integral.
:func:`reconstruction.core.metrics.image_errors` compares two renders.

Presets (:data:`PRESETS`): ``"key"`` = :class:`SkyGround` + a sun in front of the sphere (upper left, the
direction of the preview's point light), ``"rim"`` = the same sky + a sun behind the sphere (upper right,
grazing light at the lit crescent), ``"environment"`` = the sky alone.
"""

from __future__ import annotations

import hashlib
import math
from collections import OrderedDict
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]
BRDF = Callable[[Array, Array], ArrayLike]

__all__ = ["SkyGround", "Sun", "PointLight", "Lighting", "Quadrature", "PRESETS", "KEY_SUN_DIRECTION",
           "RIM_SUN_DIRECTION", "SUN_IRRADIANCE", "get_lighting", "sphere_normals", "sphere_coverage",
           "view_angle_deg", "view_angle_mask", "render_sphere", "PREVIEW_LIGHT_POSITION", "render_point_light"]

#: directions towards the two suns of the presets (world frame, normalised on use): the key light from the upper
#: left in front (the preview's point light direction), the rim light from the upper right behind the sphere
KEY_SUN_DIRECTION = (-3.0, 3.0, 5.0)
RIM_SUN_DIRECTION = (2.0, 3.0, -4.0)
#: irradiance of the presets' suns on a surface facing them (the sky gives about 2.6 to an upward surface)
SUN_IRRADIANCE = 3.0
_FRAME_EPS = 1e-9
_MAX_PAIRS = 400_000  # direction pairs per block of pixels (memory: a few arrays of this many vectors)
#: pixel-direction pairs per block of :func:`_environment_by_view` (its temporaries are scalars per pair: small
#: blocks are reused from the heap, where large ones are fresh memory mapped, faulted in and returned each time)
_VIEW_BLOCK_PAIRS = 50_000


@dataclass(frozen=True)
class SkyGround:
    """Environment radiance as a function of the world elevation (y = sin elevation): the sky rises linearly in y
    from ``horizon`` to ``zenith``, the ground is ``ground``, blended over +-``blend_deg`` of elevation by a
    smoothstep (a horizon without a step, which a fixed quadrature would show as bands)."""

    zenith: float = 1.0
    horizon: float = 0.5
    ground: float = 0.15
    blend_deg: float = 10.0

    def radiance(self, y: ArrayLike) -> Array:
        """Radiance (same units as a sun's irradiance per sr) of the directions with world up component ``y``."""
        y = np.asarray(y, dtype=np.float64)
        sky = self.horizon + (self.zenith - self.horizon) * np.clip(y, 0.0, 1.0)
        w = math.sin(math.radians(self.blend_deg))
        t = np.clip((y + w) / (2.0 * w), 0.0, 1.0) if w > 0 else (y > 0).astype(np.float64)
        t = t * t * (3.0 - 2.0 * t)
        return self.ground + (sky - self.ground) * t


@dataclass(frozen=True)
class Sun:
    """A distant light: ``direction`` (world, towards the light; normalised on use), ``irradiance`` on a surface
    facing it."""

    direction: tuple[float, float, float]
    irradiance: float = SUN_IRRADIANCE


@dataclass(frozen=True)
class PointLight:
    """A point light of ``intensity`` I at ``position`` (world, the sphere's radius 1): irradiance I cos / d^2."""

    position: tuple[float, float, float]
    intensity: float


@dataclass(frozen=True)
class Lighting:
    """What lights the sphere: an environment (or None), suns and point lights (each contribution adds)."""

    environment: SkyGround | None = None
    suns: tuple[Sun, ...] = ()
    points: tuple[PointLight, ...] = ()


PRESETS: dict[str, Lighting] = {
    "key": Lighting(SkyGround(), (Sun(KEY_SUN_DIRECTION),)),
    "rim": Lighting(SkyGround(), (Sun(RIM_SUN_DIRECTION),)),
    "environment": Lighting(SkyGround()),
}


def get_lighting(lighting: str | Lighting) -> Lighting:
    """``lighting`` itself, or the preset of that name (:data:`PRESETS`); ValueError naming the presets else."""
    if isinstance(lighting, Lighting):
        return lighting
    try:
        return PRESETS[lighting]
    except KeyError:
        raise ValueError(f"unknown lighting {lighting!r}; expected one of {', '.join(PRESETS)} or a "
                         f"Lighting") from None


@dataclass(frozen=True)
class Quadrature:
    """The environment's directions per pixel: ``n_cosine`` cosine-weighted, and ``n_per_alpha`` reflected about
    GGX visible normals for each roughness of ``alphas`` (see the module docstring)."""

    n_cosine: int = 55
    alphas: tuple[float, ...] = (0.005, 0.03, 0.12, 0.4)
    n_per_alpha: int = 55

    @property
    def n_directions(self) -> int:
        return self.n_cosine + len(self.alphas) * self.n_per_alpha


def _lattice(n: int) -> tuple[Array, Array]:
    """A 2D Fibonacci lattice of ``n`` points in [0, 1)^2 (u1 stratified, u2 by the golden ratio)."""
    k = np.arange(n, dtype=np.float64)
    return (k + 0.5) / n, np.mod(k * (math.sqrt(5.0) - 1.0) / 2.0 + 0.5 / n, 1.0)


def _cosine_dirs(n: int) -> Array:
    """(n, 3) cosine-weighted hemisphere directions (z up) from the lattice (Malley: the disc lifted)."""
    u1, u2 = _lattice(n)
    r, phi = np.sqrt(u1), 2.0 * math.pi * u2
    return np.stack([r * np.cos(phi), r * np.sin(phi), np.sqrt(np.clip(1.0 - u1, 0.0, None))], axis=-1)


def _ggx_d2(c2: Array, alpha: float) -> Array:
    """The GGX distribution D at cos^2 theta_h = ``c2``."""
    a2 = alpha * alpha
    return a2 / (math.pi * (c2 * (a2 - 1.0) + 1.0) ** 2)


def _ggx_g1(cos_v: Array, alpha: float) -> Array:
    a2 = alpha * alpha
    c = np.clip(cos_v, 0.0, 1.0)
    return 2.0 * c / (c + np.sqrt(a2 + (1.0 - a2) * c * c) + 1e-300)


def _vndf_dirs(sin_o: Array, cos_o: Array, alpha: float, n: int) -> tuple[Array, Array, Array]:
    """Components (P, n) of the directions wi reflected about GGX visible normals of wo = (sin_o, 0, cos_o)
    (P,), from the lattice (Heitz 2018, with wo in the x-z plane: the first tangent is y)."""
    u1, u2 = _lattice(n)
    ax, az = alpha * sin_o, cos_o
    inv = 1.0 / np.sqrt(ax * ax + az * az)
    vx, vz = (ax * inv)[:, None], (az * inv)[:, None]  # the view stretched to the unit-roughness configuration
    r, phi = np.sqrt(u1)[None, :], 2.0 * math.pi * u2[None, :]
    p1 = r * np.cos(phi)
    s = 0.5 * (1.0 + vz)
    p2 = (1.0 - s) * np.sqrt(np.clip(1.0 - p1 * p1, 0.0, None)) + s * r * np.sin(phi)
    p3 = np.sqrt(np.clip(1.0 - p1 * p1 - p2 * p2, 0.0, None))
    mx, my, mz = alpha * (p3 * vx - p2 * vz), alpha * p1, np.clip(p2 * vx + p3 * vz, 0.0, None)  # back-stretched
    inv = 1.0 / np.sqrt(mx * mx + my * my + mz * mz)
    mx, my, mz = mx * inv, my * inv, mz * inv
    d = 2.0 * (sin_o[:, None] * mx + cos_o[:, None] * mz)
    return d * mx - sin_o[:, None], d * my, d * mz - cos_o[:, None]


def _mixture_density(x: Array, y: Array, z: Array, sin_o: Array, cos_o: Array, q: Quadrature) -> Array:
    """sum over the strategies of n_k p_k(wi) (P, S) for directions wi = (x, y, z) (P, S) and views (P,)."""
    dens = q.n_cosine * np.clip(z, 0.0, None) / math.pi
    hx, hz = x + sin_o[:, None], z + cos_o[:, None]
    c2 = hz * hz / np.maximum(hx * hx + y * y + hz * hz, 1e-300)  # cos^2 theta_h
    co = np.maximum(cos_o, 1e-12)[:, None]
    for a in q.alphas:  # a handful of roughnesses
        dens = dens + q.n_per_alpha * _ggx_g1(co, a) * _ggx_d2(c2, a) / (4.0 * co)
    return dens


def _frames(n: Array) -> tuple[Array, Array]:
    """Per normal (P, 3): the tangent t towards the view (0, 0, 1) and the bitangent b = n x t."""
    t = np.stack([-n[:, 0] * n[:, 2], -n[:, 1] * n[:, 2], 1.0 - n[:, 2] * n[:, 2]], axis=-1)  # v - (v.n) n
    norm = np.linalg.norm(t, axis=-1, keepdims=True)
    t = np.where(norm > _FRAME_EPS, t / np.maximum(norm, _FRAME_EPS), np.array([1.0, 0.0, 0.0]))
    return t, np.cross(n, t)


def _pixel_grid(size: int, radius: float) -> tuple[Array, Array]:
    c = ((np.arange(size) + 0.5) / size * 2.0 - 1.0) / radius
    x, y = np.meshgrid(c, -c)  # y up, row 0 on top
    return x, y


def sphere_coverage(size: int, radius: float = 1.0, antialias: bool = False) -> Array:
    """(size, size) fraction of each pixel the sphere covers: 1 inside, 0 outside; with ``antialias`` the
    boundary pixels get the fraction of their width inside the disc (a signed-distance estimate of the area),
    else a pixel counts when its centre is inside."""
    x, y = _pixel_grid(size, radius)
    r = np.sqrt(x * x + y * y)
    if not antialias:
        return (r < 1.0).astype(np.float64)
    px = 2.0 / (size * radius)  # a pixel's width in sphere radii
    return np.clip(0.5 + (1.0 - r) / px, 0.0, 1.0)


def sphere_normals(size: int, radius: float = 1.0, antialias: bool = False) -> tuple[NDArray[np.bool_], Array]:
    """(mask (size, size) of the pixels rendered, their normals (P, 3) in row-major order): the pixels whose
    centre is inside the disc or, with ``antialias``, that the sphere partly covers (their normal at the
    nearest point of the disc, n_z at least 1e-3)."""
    x, y = _pixel_grid(size, radius)
    cov = sphere_coverage(size, radius, antialias)
    mask = cov > 0
    px, py = x[mask], y[mask]
    r = np.sqrt(px * px + py * py)
    rmax = math.sqrt(1.0 - 1e-6)
    k = np.where(r > rmax, rmax / np.maximum(r, 1e-300), 1.0)
    px, py = px * k, py * k
    return mask, np.stack([px, py, np.sqrt(np.clip(1.0 - px * px - py * py, 0.0, None))], axis=-1)


def view_angle_deg(size: int, radius: float = 1.0) -> Array:
    """(size, size) view angle theta_o (degrees) of each pixel centre on the sphere; NaN outside it."""
    x, y = _pixel_grid(size, radius)
    r2 = x * x + y * y
    with np.errstate(invalid="ignore"):
        return np.where(r2 < 1.0, np.degrees(np.arccos(np.sqrt(np.clip(1.0 - r2, 0.0, 1.0)))), np.nan)


def view_angle_mask(size: int, radius: float = 1.0, max_view_deg: float = 80.0) -> NDArray[np.bool_]:
    """(size, size) True on the pixels whose centre is on the sphere with a view angle <= ``max_view_deg``."""
    va = view_angle_deg(size, radius)
    return np.isfinite(va) & (va <= max_view_deg + 1e-9)


def _eval(f: BRDF, wi: Array, wo: Array) -> Array:
    """f at the pairs (N, 3) as (N, C), non-finite values 0 (C from one pair at normal incidence when N = 0)."""
    if wi.shape[0] == 0:
        z = np.array([[0.0, 0.0, 1.0]])
        return np.zeros((0, np.asarray(f(z, z), dtype=np.float64).reshape(1, -1).shape[1]))
    v = np.asarray(f(wi, wo), dtype=np.float64)
    return np.nan_to_num(v.reshape(wi.shape[0], -1), nan=0.0, posinf=0.0, neginf=0.0)


def _environment_pairs(env: SkyGround, n: Array, t: Array, b: Array,
                       q: Quadrature) -> Iterator[tuple[NDArray[np.intp], Array, Array, Array]]:
    """The environment's quadrature at the normals ``n`` with frames (t, b), in blocks of pixels: per block the
    pixel indices (N,) into ``n``, the direction pairs wi, wo (N, 3) and their weights (N,), so that the radiance
    of pixel p is the sum over its pairs of f(wi, wo) x weight."""
    cd = _cosine_dirs(q.n_cosine)
    block = max(1, _MAX_PAIRS // max(q.n_directions, 1))
    for lo in range(0, n.shape[0], block):  # blocks of pixels, for memory; every direction of a block at once
        nn, tt, bb = n[lo:lo + block], t[lo:lo + block], b[lo:lo + block]
        p = nn.shape[0]
        cos_o = np.clip(nn[:, 2], 0.0, 1.0)
        sin_o = np.sqrt(np.clip(1.0 - cos_o * cos_o, 0.0, None))
        comps = [tuple(np.broadcast_to(cd[:, k], (p, q.n_cosine)) for k in range(3))]
        comps += [_vndf_dirs(sin_o, cos_o, a, q.n_per_alpha) for a in q.alphas]
        x, y, z = (np.concatenate([c[k] for c in comps], axis=1) for k in range(3))  # (p, S) local directions
        # each direction and its mirror image in the plane of wo (y -> -y), where an isotropic f takes the same
        # value: the environment at both, for one evaluation of f (antithetic pairs, no cost in f)
        up = x * tt[:, 1:2] + z * nn[:, 1:2]
        side = y * bb[:, 1:2]
        env_pair = 0.5 * (env.radiance(up + side) + env.radiance(up - side))
        weight = np.where(z > 0, env_pair * z, 0.0) / np.maximum(_mixture_density(x, y, z, sin_o, cos_o, q), 1e-300)
        lit = weight > 0
        pix = np.nonzero(lit)[0]
        wi = np.stack([x[lit], y[lit], z[lit]], axis=-1)
        wo = np.stack([sin_o[pix], np.zeros(pix.size), cos_o[pix]], axis=-1)
        yield pix + lo, wi, wo, weight[lit]


def _environment_by_view(f: BRDF, env: SkyGround, n: Array, t: Array, b: Array, q: Quadrature) -> Array:
    """The environment's radiance (P, C) at the normals ``n`` with frames (t, b), as the sum over the pairs of
    :func:`_environment_pairs`, with f evaluated once per distinct view angle: a pixel's local pairs (wi, wo) and
    their densities depend on its view angle alone (wo = (sin, 0, cos) theta_o), so the pixels at the same
    distance from the disc's centre (8 by the grid's symmetry) share them; only the environment's radiance at
    each direction is per pixel. The same sums as the pairs give, for an eighth of the evaluations of f."""
    cos_o = np.clip(n[:, 2], 0.0, 1.0)
    views, inv = np.unique(cos_o, return_inverse=True)  # (U,), and each pixel's view
    sin_v = np.sqrt(np.clip(1.0 - views * views, 0.0, None))
    cd = _cosine_dirs(q.n_cosine)
    comps = [tuple(np.broadcast_to(cd[:, k], (views.size, q.n_cosine)) for k in range(3))]
    comps += [_vndf_dirs(sin_v, views, a, q.n_per_alpha) for a in q.alphas]
    x, y, z = (np.concatenate([c[k] for c in comps], axis=1) for k in range(3))  # (U, S) local directions
    base = np.where(z > 0, z, 0.0) / np.maximum(_mixture_density(x, y, z, sin_v, views, q), 1e-300)  # (U, S)
    uu, ss = np.nonzero(base > 0)
    vals = _eval(f, np.stack([x[uu, ss], y[uu, ss], z[uu, ss]], axis=-1),
                 np.stack([sin_v[uu], np.zeros(uu.size), views[uu]], axis=-1))  # f once per view and direction
    fv = np.zeros((views.size, x.shape[1], vals.shape[1]))
    fv[uu, ss] = vals
    rad = np.zeros((n.shape[0], vals.shape[1]))
    block = max(1, _VIEW_BLOCK_PAIRS // max(q.n_directions, 1))
    for lo in range(0, n.shape[0], block):  # blocks of pixels: temporaries of a few hundred kB each
        k = inv[lo:lo + block]
        up = x[k] * t[lo:lo + block, 1:2] + z[k] * n[lo:lo + block, 1:2]
        side = y[k] * b[lo:lo + block, 1:2]
        env_pair = 0.5 * (env.radiance(up + side) + env.radiance(up - side))  # antithetic pairs (as the pairs)
        rad[lo:lo + block] = np.einsum("ps,psc->pc", env_pair * base[k], fv[k])
    return rad


def _direct_pairs(lighting: Lighting, n: Array, t: Array,
                  b: Array) -> Iterator[tuple[NDArray[np.intp], Array, Array, Array]]:
    """The suns and point lights at the normals ``n`` with frames (t, b): per light the pixel indices (N,), the
    pairs wi, wo (N, 3) and the weights irradiance x cos theta_i (N,) (only the pixels the light reaches)."""
    cos_o = np.clip(n[:, 2], 0.0, 1.0)
    wo = np.stack([np.sqrt(np.clip(1.0 - cos_o * cos_o, 0.0, None)), np.zeros_like(cos_o), cos_o], axis=-1)
    lights: list[tuple[Array, Array]] = []
    for sun in lighting.suns:  # a few lights
        d = np.asarray(sun.direction, dtype=np.float64)
        lights.append((np.broadcast_to(d / np.linalg.norm(d), n.shape), np.full(n.shape[0], float(sun.irradiance))))
    for pl in lighting.points:
        to_l = np.asarray(pl.position, dtype=np.float64)[None, :] - n
        d2 = np.sum(to_l * to_l, axis=-1)
        lights.append((to_l / np.sqrt(d2)[:, None], float(pl.intensity) / d2))
    for d, irr in lights:
        wi = np.stack([np.sum(d * t, -1), np.sum(d * b, -1), np.sum(d * n, -1)], axis=-1)
        lit = np.nonzero(wi[:, 2] > 0)[0]
        yield lit, wi[lit], wo[lit], irr[lit] * wi[lit, 2]


def _gather(f: BRDF, pairs: Iterator[tuple[NDArray[np.intp], Array, Array, Array]], n_pix: int) -> Array | None:
    """sum over the ``pairs`` of f(wi, wo) x weight per pixel: (n_pix, C), or None without any block."""
    acc: Array | None = None
    for pix, wi, wo, w in pairs:
        vals = _eval(f, wi, wo) * w[:, None]
        if acc is None:
            acc = np.zeros((n_pix, vals.shape[1]))
        for c in range(vals.shape[1]):  # 1 or 3 channels
            acc[:, c] += np.bincount(pix, weights=vals[:, c], minlength=n_pix)
    return acc


# --- tables: a BRDF linear in the cells of a table, rendered as one sparse product ----------------------------

#: operators kept per process (each a few hundred MB at most for 128 x 128 pixels)
_OPERATOR_CACHE_SIZE = 4
_operators: OrderedDict[tuple[Any, ...], Any] = OrderedDict()


def _table_operator(key: tuple[Any, ...], cells: Callable[[Array, Array], tuple[NDArray[np.intp], Array]],
                    finite: NDArray[np.bool_], pairs: Callable[[], Iterator[tuple[NDArray[np.intp], Array, Array,
                                                                                     Array]]],
                    n_pix: int) -> Any:
    """The sparse matrix (n_pix, n_cells) M with radiance = M @ table (channels as columns): the quadrature
    ``pairs`` of a part of the lighting, each pair's table cells and weights from ``cells(wi, wo)`` (N, K), the
    weights renormalised over the ``finite`` cells (n_cells,) as the table's lookup does (0 where none is).
    Built once per ``key`` (the image geometry, the lighting part, the lookup and the finite cells) and cached."""
    from scipy import sparse

    if key in _operators:
        _operators.move_to_end(key)
        return _operators[key]
    m = None
    for pix, wi, wo, w in pairs():
        idx, cw = cells(wi, wo)
        cw = cw * finite[idx]
        tot = cw.sum(axis=1)
        ok = tot > 1e-12
        data = np.where(ok[:, None], cw * (w / np.where(ok, tot, 1.0))[:, None], 0.0)
        rows = np.broadcast_to(pix[:, None], idx.shape)
        part = sparse.csr_matrix((data.ravel(), (rows.ravel(), idx.ravel())), shape=(n_pix, finite.size))
        part.sum_duplicates()
        m = part if m is None else m + part
    if m is None:
        m = sparse.csr_matrix((n_pix, finite.size))
    m.eliminate_zeros()
    _operators[key] = m
    while len(_operators) > _OPERATOR_CACHE_SIZE:
        _operators.popitem(last=False)
    return m


def _render_table(f: BRDF, light: Lighting, n: Array, t: Array, b: Array, q: Quadrature,
                  geometry: tuple[Any, ...]) -> Array | None:
    """Radiance (P, C) of a BRDF that is a lookup in a table (``f.table_cells``, ``f.table``: see
    :func:`reconstruction.core.merltable.brdf_of`) as sparse products with cached operators, or None when the table's
    channels have different finite cells (then the generic path renders it)."""
    cells = f.table_cells  # type: ignore[attr-defined]
    table = np.asarray(f.table, dtype=np.float64)  # type: ignore[attr-defined]
    flat = table.reshape(table.shape[0], -1)
    fin = np.isfinite(flat)
    finite = fin[0]
    if not np.array_equal(fin.all(axis=0), fin.any(axis=0)):
        return None
    digest = "all" if finite.all() else hashlib.blake2b(np.packbits(finite).tobytes(), digest_size=16).hexdigest()
    base = geometry + (getattr(f, "table_lookup", ""), digest)
    x = np.ascontiguousarray(np.where(fin, flat, 0.0).T)  # (n_cells, C)
    rad = np.zeros((n.shape[0], flat.shape[0]))
    if light.environment is not None:
        m = _table_operator(base + ("environment", light.environment, q), cells, finite,
                            lambda: _environment_pairs(light.environment, n, t, b, q), n.shape[0])
        rad += m @ x
    if light.suns or light.points:
        m = _table_operator(base + ("direct", light.suns, light.points), cells, finite,
                            lambda: _direct_pairs(light, n, t, b), n.shape[0])
        rad += m @ x
    return rad


def render_sphere(f: BRDF, size: int = 128, lighting: str | Lighting = "key", radius: float = 1.0,
                  antialias: bool = False, quadrature: Quadrature | None = None) -> Array:
    """Render the sphere with the BRDF ``f(wi, wo) -> (..., C)`` (1/sr, unit vectors in the local frame, z = the
    normal) under ``lighting`` (a :class:`Lighting` or a preset name of :data:`PRESETS`).

    Returns (size, size, C) float64 linear radiance, row 0 on top: the sphere's radiance times its
    :func:`sphere_coverage` (so 0 outside the sphere; composite a background with 1 - coverage). ``radius``: the
    sphere's radius as a fraction of the half frame. Deterministic (the same image at every call); about 0.6 s
    of one core for 128 x 128 pixels of an analytic BRDF with the default :class:`Quadrature`
    (benchmarks/bench_render.py).

    A table's BRDF (``f.table`` and ``f.table_cells``, as :func:`reconstruction.core.merltable.brdf_of` gives) is
    rendered as one sparse product: each pixel's pairs, their table cells and weights (renormalised over the
    table's finite cells, as the lookup does) are gathered once per image size, radius, lighting part, lookup and
    set of finite cells into a matrix (cached per process), so a table renders in a small fraction of the generic
    path's time with the same values (tests/test_render_table.py; benchmarks/bench_render.py times both).
    """
    light = get_lighting(lighting)
    if light.environment is None and not light.suns and not light.points:
        raise ValueError("lighting has no environment, sun or point light")
    q = quadrature or Quadrature()
    mask, n = sphere_normals(size, radius, antialias)
    t, b = _frames(n)
    rad = None
    if getattr(f, "table_cells", None) is not None:  # a table: cached sparse operators, the same values
        rad = _render_table(f, light, n, t, b, q, (size, radius, antialias))
    if rad is None:
        parts = []
        if light.environment is not None:
            parts.append(_environment_by_view(f, light.environment, n, t, b, q))
        parts.append(_gather(f, _direct_pairs(light, n, t, b), n.shape[0]))
        parts = [p for p in parts if p is not None]
        if not parts:  # no pixel lit at all: the channels from one evaluation
            parts = [_eval(f, np.zeros((0, 3)), np.zeros((0, 3)))]
        n_c = max(p.shape[1] for p in parts)
        rad = sum(np.broadcast_to(p, (n.shape[0], n_c)) for p in parts)
    n_c = rad.shape[1]
    img = np.zeros((size, size, n_c))
    img[mask] = np.maximum(rad, 0.0) * sphere_coverage(size, radius, antialias)[mask][:, None]
    return img


#: The preview's point light (world frame, sphere of radius 1 at the origin); intensity |p|^2 (irradiance 1 at the
#: origin).
PREVIEW_LIGHT_POSITION = np.array([-3.0, 3.0, 5.0])


def render_point_light(f: Callable[[Array, Array], ArrayLike], size: int = 256,
                       light_position: ArrayLike = PREVIEW_LIGHT_POSITION, radius: float = 1.0) -> NDArray[np.float32]:
    """Render the sphere with BRDF ``f(wi, wo) -> (N, 1 | 3)`` (1/sr) under the point light
    at ``light_position`` (:data:`PREVIEW_LIGHT_POSITION`: the preview's and the sphere error metric's light), a
    :class:`PointLight` through :func:`render_sphere`.

    ``radius``: the sphere's radius as a fraction of the half frame (1 fills the frame). Returns (size, size, 3)
    float32 linear RGB, row 0 on top, 0 outside the sphere.
    """
    lp = np.asarray(light_position, dtype=np.float64)
    img = render_sphere(f, size, Lighting(points=(PointLight((float(lp[0]), float(lp[1]), float(lp[2])),
                                                      float(lp @ lp)),)), radius)
    return (np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img).astype(np.float32)
