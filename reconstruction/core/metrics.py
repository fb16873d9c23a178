"""Error metrics and physical plausibility checks for BRDFs (functions of direction pairs or MERL tables)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.core.geometry import inplane_to_dirs, sph_to_vec

Array = NDArray[np.float64]
BRDF = Callable[[Array, Array], ArrayLike]

__all__ = ["hemisphere_quadrature", "directional_albedo", "reciprocity_error", "relative_rmse_cos",
           "relative_rmse_cos_by_theta_d", "log_rmse", "sphere_relative_error", "albedo_error", "table_errors",
           "relative_rmse_cos_dirs", "within_angle_mask", "median_relative_error", "halfvector_albedo",
           "IMAGE_MAX_VIEW_DEG", "IMAGE_GAMMA", "IMAGE_EXPOSURE_PERCENTILE", "image_exposure", "tone_map",
           "image_psnr", "image_relative_rmse", "image_errors", "uniform_pairs", "cosl2", "log_error", "LOG_EPS"]


def hemisphere_quadrature(n_theta: int = 128, n_phi: int = 256) -> tuple[Array, Array]:
    """Directions (n_theta * n_phi, 3) and weights (sr) over the upper hemisphere, weights include cos theta.

    Gauss-Legendre in cos theta and the midpoint rule in phi, so sum(w * g(wo)) ~ integral of g cos dw.
    """
    x, wx = np.polynomial.legendre.leggauss(n_theta)
    mu = 0.5 * (x + 1.0)  # cos theta in (0, 1)
    wmu = 0.5 * wx
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    theta = np.arccos(mu)
    dirs = sph_to_vec(theta[:, None], phi[None, :]).reshape(-1, 3)
    w = (wmu * mu)[:, None] * np.full(n_phi, 2 * np.pi / n_phi)[None, :]
    return dirs, w.reshape(-1)


def directional_albedo(f: BRDF, theta_i: ArrayLike, n_theta: int = 128, n_phi: int = 256,
                       mirror: bool = False) -> Array:
    """Directional albedo a(theta_i) = integral of f(wi, wo) cos theta_o d wo, shape (len(theta_i), C).

    ``theta_i`` in radians; ``f(wi, wo) -> (N, C)`` vectorised. A passive, energy-conserving BRDF has a <= 1.
    With ``mirror`` (``f`` symmetric about the plane of incidence, as every isotropic BRDF is) only the nodes of
    phi in (0, pi) are evaluated, at twice the weight: the same sum as the whole grid's (``n_phi`` even) for half
    the evaluations.
    """
    ti = np.atleast_1d(np.asarray(theta_i, dtype=np.float64))
    wo, w = hemisphere_quadrature(n_theta, n_phi)
    if mirror:  # the midpoint nodes k and n_phi - 1 - k are mirror images (phi and 2 pi - phi)
        if n_phi % 2:
            raise ValueError(f"directional_albedo: mirror needs an even n_phi, got {n_phi}")
        wo = wo.reshape(n_theta, n_phi, 3)[:, : n_phi // 2].reshape(-1, 3)
        w = 2.0 * w.reshape(n_theta, n_phi)[:, : n_phi // 2].reshape(-1)
    out = []
    for t in ti:  # one vectorised hemisphere integral per incidence
        wi, _ = inplane_to_dirs(t, 0.0)
        v = np.asarray(f(np.broadcast_to(wi, wo.shape), wo), dtype=np.float64).reshape(wo.shape[0], -1)
        out.append(w @ v)
    return np.array(out)


def halfvector_albedo(f: BRDF, theta_i: ArrayLike, n_panels: int = 48, n_gauss: int = 8, n_phi: int = 256,
                      theta_h_min: float = 1e-5) -> Array:
    """Directional albedo (len(theta_i), C) integrated over the half vector, for BRDFs with a sharp specular peak.

    a(theta_i) = integral of f(wi, wo(h)) cos(theta_o) 4 (wi . h) d omega_h with wo the mirror of wi about h:
    theta_h on geometric panels from ``theta_h_min`` (radians) to pi/2 (Gauss-Legendre in each), phi_h by the
    midpoint rule; the peak at h = n is resolved whatever its width (ggx alpha 1e-3, a MERL table's finest cells).
    """
    ti = np.atleast_1d(np.asarray(theta_i, dtype=np.float64))
    edges = np.concatenate([[0.0], np.geomspace(theta_h_min, np.pi / 2, n_panels)])
    x, wx = np.polynomial.legendre.leggauss(n_gauss)
    lo, hi = edges[:-1, None], edges[1:, None]
    th = (0.5 * (hi - lo) * (x[None, :] + 1.0) + lo).ravel()
    wth = (0.5 * (hi - lo) * wx[None, :]).ravel() * np.sin(th)
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    h = sph_to_vec(th[:, None], phi[None, :]).reshape(-1, 3)
    w = np.repeat(wth, n_phi) * (2 * np.pi / n_phi)
    out = []
    for t in ti:  # one vectorised integral per incidence
        wi, _ = inplane_to_dirs(t, 0.0)
        c = h @ wi
        wo = 2.0 * c[:, None] * h - wi
        ok = (c > 0) & (wo[:, 2] > 0)
        v = np.asarray(f(np.broadcast_to(wi, wo.shape)[ok], wo[ok]), dtype=np.float64).reshape(int(ok.sum()), -1)
        v = np.nan_to_num(v, nan=0.0)
        out.append((w[ok] * wo[ok, 2] * 4.0 * c[ok]) @ v)
    return np.array(out)


def reciprocity_error(f: BRDF, n: int = 4096, seed: int = 0) -> float:
    """max |f(wi, wo) - f(wo, wi)| / max(|f|) over ``n`` random upper-hemisphere direction pairs."""
    rng = np.random.default_rng(seed)
    a = sph_to_vec(np.arccos(rng.uniform(0.01, 1, n)), rng.uniform(0, 2 * np.pi, n))
    b = sph_to_vec(np.arccos(rng.uniform(0.01, 1, n)), rng.uniform(0, 2 * np.pi, n))
    fab = np.asarray(f(a, b), dtype=np.float64)
    fba = np.asarray(f(b, a), dtype=np.float64)
    scale = max(float(np.max(np.abs(fab))), 1e-300)
    return float(np.max(np.abs(fab - fba)) / scale)


def _table_cosines() -> Array:
    """cos(theta_i) cos(theta_o) at every MERL cell's bin-centre directions, (90, 90, 180); 0 below the horizon."""
    from reconstruction.core.merlgrid import _cell_dirs

    wi, wo = _cell_dirs()
    return np.clip(wi[..., 2], 0.0, None) * np.clip(wo[..., 2], 0.0, None)


def within_angle_mask(max_theta_deg: float | None = None) -> NDArray[np.bool_]:
    """(90, 90, 180) bool: MERL cells above the horizon whose bin-centre theta_i and theta_o are both
    <= ``max_theta_deg`` (all cells above the horizon when None)."""
    from reconstruction.core.merlgrid import _cell_dirs, valid_mask

    m = valid_mask()
    if max_theta_deg is None:
        return m
    wi, wo = _cell_dirs()
    c = np.cos(np.radians(max_theta_deg)) - 1e-12
    return m & (wi[..., 2] >= c) & (wo[..., 2] >= c)


def relative_rmse_cos(table: ArrayLike, truth_table: ArrayLike, max_theta_deg: float | None = None) -> float:
    """Relative RMSE of f cos(theta_i) cos(theta_o) between two MERL tables (3, 90, 90, 180), over valid cells.

    sqrt(sum((f - g)^2 c^2) / sum(g^2 c^2)) with c = cos theta_i cos theta_o at the bin centres, pooled over the
    three channels and over every cell above the horizon where both tables are finite (and, with
    ``max_theta_deg``, whose theta_i and theta_o are both within it: "rmse80" is ``max_theta_deg=80``).
    Dimensionless; 0.02 = 2 %.
    """
    return float(np.sqrt(np.sum(relative_rmse_cos_by_theta_d(table, truth_table, max_theta_deg, (0.0, 90.0)) ** 2)))


def relative_rmse_cos_by_theta_d(table: ArrayLike, truth_table: ArrayLike, max_theta_deg: float | None = None,
                                 edges_deg: tuple[float, ...] = (0.0, 30.0, 45.0, 60.0, 90.0)) -> Array:
    """:func:`relative_rmse_cos` split by the difference angle theta_d (bands between ``edges_deg``, deg):
    (len(edges_deg) - 1,) parts e_k = sqrt(sum over band k of (f - g)^2 c^2 / sum over all cells of g^2 c^2), so
    that sum(e_k^2) = relative_rmse_cos^2. Shows where an error comes from (grazing theta_d, which no
    low-incidence slice sees, or the measured range). Dimensionless."""
    from reconstruction.core.merltable import SHAPE

    f = np.asarray(table, dtype=np.float64)
    g = np.asarray(truth_table, dtype=np.float64)
    if f.shape != SHAPE or g.shape != SHAPE:
        raise ValueError(f"tables must have shape {SHAPE}, got {f.shape} and {g.shape}")
    c = _table_cosines()[None]
    ok = within_angle_mask(max_theta_deg)[None] & np.isfinite(f) & np.isfinite(g)
    den = np.sum(np.where(ok, g * c, 0.0) ** 2)
    err2 = np.sum(np.where(ok, (f - g) * c, 0.0) ** 2, axis=(0, 1, 3))  # per theta_d bin (90,)
    td = np.arange(SHAPE[2]) + 0.5  # MERL theta_d bin centres, deg
    e = np.asarray(edges_deg, dtype=np.float64)
    parts = np.array([err2[(td >= lo) & (td < hi)].sum() for lo, hi in zip(e[:-1], e[1:], strict=True)])
    return np.sqrt(parts / den) if den > 0 else np.full(parts.shape, np.inf)


def median_relative_error(table: ArrayLike, truth_table: ArrayLike, max_theta_deg: float | None = 80.0,
                          min_fraction: float = 0.01) -> float:
    """Median of |f - g| / g over the cells (every channel) where the truth g is above ``min_fraction`` of its
    channel's maximum, within ``max_theta_deg`` (see :func:`within_angle_mask`). Dimensionless."""
    f = np.asarray(table, dtype=np.float64)
    g = np.asarray(truth_table, dtype=np.float64)
    ok = within_angle_mask(max_theta_deg)[None] & np.isfinite(f) & np.isfinite(g)
    peak = np.max(np.where(ok, g, -np.inf), axis=(1, 2, 3), keepdims=True)
    big = ok & (g > min_fraction * peak)
    return float(np.median(np.abs(f[big] - g[big]) / g[big])) if big.any() else float("inf")


def relative_rmse_cos_dirs(f: ArrayLike, g: ArrayLike, wi: ArrayLike, wo: ArrayLike) -> float:
    """Relative RMSE of f cos(theta_i) cos(theta_o) between two sets of BRDF values (N, C) at direction pairs.

    ``f``, ``g``: (N, C) in 1/sr (``g`` is the reference); ``wi``, ``wo``: (N, 3). Pooled over channels; pairs
    where either value is non-finite are ignored. Dimensionless.
    """
    f = np.asarray(f, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    c = (np.clip(wi[..., 2], 0.0, None) * np.clip(wo[..., 2], 0.0, None)).reshape(-1, 1)
    f = f.reshape(c.shape[0], -1)
    g = g.reshape(c.shape[0], -1)
    ok = np.isfinite(f) & np.isfinite(g)
    num = np.sum(np.where(ok, (f - g) * c, 0.0) ** 2)
    den = np.sum(np.where(ok, g * c, 0.0) ** 2)
    return float(np.sqrt(num / den)) if den > 0 else float("inf")


def log_rmse(table: ArrayLike, truth_table: ArrayLike, eps: float = 1e-3) -> float:
    """RMSE of ln(f cos_i cos_o + eps) - ln(g cos_i cos_o + eps) over valid cells of two MERL tables.

    ``eps`` (1/sr) keeps the logarithm finite where a BRDF is 0; the metric weighs a lobe's shape and the dim
    floor alike, unlike :func:`relative_rmse_cos`, which the peak dominates. Pooled over the 3 channels.
    """
    from reconstruction.core.merlgrid import valid_mask

    f = np.asarray(table, dtype=np.float64)
    g = np.asarray(truth_table, dtype=np.float64)
    c = _table_cosines()[None]
    ok = valid_mask()[None] & np.isfinite(f) & np.isfinite(g)
    d = np.log(np.clip(f, 0, None) * c + eps) - np.log(np.clip(g, 0, None) * c + eps)
    n = int(ok.sum())
    return float(np.sqrt(np.sum(np.where(ok, d, 0.0) ** 2) / n)) if n else float("inf")


def sphere_relative_error(table: ArrayLike, truth_table: ArrayLike, size: int = 128) -> float:
    """Relative L2 error ||A - B|| / ||B|| of the preview sphere rendered with two MERL tables (all pixels, RGB).

    The sphere and light of the preview (:func:`reconstruction.core.render.render_point_light`); tables read with
    interpolation.
    """
    from reconstruction.core.merltable import brdf_of
    from reconstruction.core.render import render_point_light

    a = render_point_light(brdf_of(table), size).astype(np.float64)
    b = render_point_light(brdf_of(truth_table), size).astype(np.float64)
    den = float(np.sqrt(np.sum(b * b)))
    return float(np.sqrt(np.sum((a - b) ** 2)) / den) if den > 0 else float("inf")


def albedo_error(table: ArrayLike, truth_table: ArrayLike,
                 theta_i_deg: ArrayLike = (0.0, 20.0, 40.0, 60.0, 80.0)) -> dict[str, list[float] | float]:
    """Directional albedo of two MERL tables read as a renderer does (nearest cell), per incidence.

    Returns ``theta_i_deg``, ``albedo`` and ``truth_albedo`` (channel means) and ``max_abs_error``.
    """
    from reconstruction.core.merltable import brdf_of

    ti = np.radians(np.asarray(theta_i_deg, dtype=np.float64))
    a = directional_albedo(brdf_of(table, interpolate=False), ti).mean(axis=1)
    b = directional_albedo(brdf_of(truth_table, interpolate=False), ti).mean(axis=1)
    return {"theta_i_deg": np.degrees(ti).tolist(), "albedo": a.tolist(), "truth_albedo": b.tolist(),
            "max_abs_error": float(np.max(np.abs(a - b)))}


def table_errors(table: ArrayLike, truth_table: ArrayLike) -> dict[str, float]:
    """All full-table error figures against a ground truth: relative RMSE of f cos cos, log RMSE, sphere
    render error and the largest directional-albedo error over theta_i = 0..80 deg."""
    return {
        "rel_rmse_cos": relative_rmse_cos(table, truth_table),
        "log_rmse": log_rmse(table, truth_table),
        "sphere_rel_error": sphere_relative_error(table, truth_table),
        "albedo_max_abs_error": float(albedo_error(table, truth_table)["max_abs_error"]),
    }


# --- images: a BRDF as a renderer sees it (reconstruction.core.render) --------------------------------------------

#: pixels of the sphere seen at a view angle above this (degrees) are left out of the image metrics
IMAGE_MAX_VIEW_DEG = 80.0
#: the display gamma of the tone-mapped images, and the percentile of the truth exposed to 1
IMAGE_GAMMA = 2.2
IMAGE_EXPOSURE_PERCENTILE = 99.5


def _pixels(img: ArrayLike, mask: NDArray[np.bool_] | None) -> Array:
    a = np.asarray(img, dtype=np.float64)
    a = a[..., None] if a.ndim == 2 else a
    return a[mask] if mask is not None else a.reshape(-1, a.shape[-1])


def image_exposure(truth: ArrayLike, mask: NDArray[np.bool_] | None = None) -> float:
    """The linear multiplier that maps the :data:`IMAGE_EXPOSURE_PERCENTILE` th percentile of the ``truth``
    image's values (every channel of the pixels in ``mask``, (H, W) bool; all pixels when None) to 1 (1 for a
    black image)."""
    v = _pixels(truth, mask)
    p = float(np.percentile(v, IMAGE_EXPOSURE_PERCENTILE)) if v.size else 0.0
    return 1.0 / p if p > 0 else 1.0


def tone_map(img: ArrayLike, exposure: float) -> Array:
    """Display values in [0, 1]: (linear ``img`` x ``exposure``), clipped to [0, 1], to the power 1 / 2.2."""
    return np.clip(np.asarray(img, dtype=np.float64) * exposure, 0.0, 1.0) ** (1.0 / IMAGE_GAMMA)


def image_psnr(img: ArrayLike, truth: ArrayLike, mask: NDArray[np.bool_] | None = None) -> float:
    """PSNR (dB) of the tone-mapped ``img`` against the tone-mapped ``truth`` (both linear (H, W, C); the
    exposure of :func:`image_exposure` from the truth), over the pixels of ``mask`` and every channel: 10 log10(1 /
    mean squared difference); inf for identical images."""
    e = image_exposure(truth, mask)
    a, b = _pixels(tone_map(img, e), mask), _pixels(tone_map(truth, e), mask)
    a, b = np.broadcast_arrays(a, b)
    mse = float(np.mean((a - b) ** 2)) if a.size else 0.0
    return 10.0 * float(np.log10(1.0 / mse)) if mse > 0 else float("inf")


def image_relative_rmse(img: ArrayLike, truth: ArrayLike, mask: NDArray[np.bool_] | None = None,
                        leave_out_brightest: int = 0) -> float:
    """Relative RMSE of the linear images: sqrt(sum (img - truth)^2 / sum truth^2) over the pixels of ``mask``
    and every channel. Dimensionless (inf for a black truth).

    ``leave_out_brightest``: that many pixels, the brightest of ``truth`` (sum over channels), left out of both
    sums. On a glossy sphere under a sun the linear error is the highlight's few pixels: their value is f at a
    theta_h finer than a bench's step (merl-violet-acrylic from one 40 deg slice: 89 % with every pixel, 15 %
    without the single brightest).

    Examples
    --------
    >>> truth = np.array([[1.0], [1.0], [100.0]])
    >>> round(image_relative_rmse(np.array([[1.0], [1.0], [50.0]]), truth), 3)
    0.5
    >>> image_relative_rmse(np.array([[1.0], [1.0], [50.0]]), truth, leave_out_brightest=1)
    0.0
    """
    a, b = np.broadcast_arrays(_pixels(img, mask), _pixels(truth, mask))
    if leave_out_brightest > 0:
        keep = np.argsort(-np.sum(b, axis=-1), kind="stable")[leave_out_brightest:]
        a, b = a[keep], b[keep]
    den = float(np.sum(b * b))
    return float(np.sqrt(np.sum((a - b) ** 2) / den)) if den > 0 else float("inf")


def image_errors(f: BRDF, truth: BRDF, size: int = 128, lightings: tuple[str, ...] = ("key", "rim"),
                 max_view_deg: float = IMAGE_MAX_VIEW_DEG) -> dict[str, dict[str, float]]:
    """``f`` against ``truth`` (BRDFs of local unit vectors) as :func:`reconstruction.core.render.render_sphere` shows
    them: per lighting preset, ``psnr_db`` of the tone-mapped images and ``relative_rmse`` of the linear ones over
    the pixels seen at a view angle <= ``max_view_deg``."""
    from reconstruction.core.render import render_sphere, view_angle_mask

    mask = view_angle_mask(size, 1.0, max_view_deg)
    out = {}
    for name in lightings:  # two presets
        a, b = render_sphere(f, size, name), render_sphere(truth, size, name)
        out[name] = {"psnr_db": image_psnr(a, b, mask), "relative_rmse": image_relative_rmse(a, b, mask)}
    return out


# --- direction pairs drawn uniformly: the field's BRDF-space metrics ----------------------------------------------

#: the offset (1/sr) of :func:`log_error`, which keeps the logarithm finite where f cos theta_i is 0
LOG_EPS = 1e-3


def uniform_pairs(n: int = 200_000, max_theta_deg: float = 80.0, seed: int = 0) -> tuple[Array, Array]:
    """``n`` direction pairs (wi, wo), each (n, 3), drawn independently and uniformly in solid angle over the cap
    theta <= ``max_theta_deg`` (cos theta uniform, phi uniform): deterministic for a ``seed``."""
    rng = np.random.default_rng(seed)
    c = np.cos(np.radians(max_theta_deg))
    u = rng.uniform(c, 1.0, (2, n))
    phi = rng.uniform(0.0, 2.0 * np.pi, (2, n))
    d = sph_to_vec(np.arccos(u), phi)
    return d[0], d[1]


def cosl2(f: ArrayLike, g: ArrayLike, wi: ArrayLike, wo: ArrayLike) -> float:
    """Relative cosine-weighted L2 of ``f`` against the reference ``g`` (both (N, C), 1/sr) at pairs (N, 3) that
    were drawn uniformly in solid angle (:func:`uniform_pairs`): sqrt(sum ((f - g) cos ti cos to)^2 / sum
    (g cos ti cos to)^2), pooled over channels (Ngan, Durand and Matusik 2005's metric, made relative).
    Dimensionless; 0 for f = g."""
    return relative_rmse_cos_dirs(f, g, wi, wo)


def log_error(f: ArrayLike, g: ArrayLike, wi: ArrayLike, eps: float = LOG_EPS) -> float:
    """Mean |ln((f cos ti + eps) / (g cos ti + eps))| over pairs drawn uniformly (``f``, ``g`` (N, C) in 1/sr,
    ``wi`` (N, 3)), every channel; pairs where either value is non-finite are ignored. Weighs the dim parts of a
    BRDF as much as its peak (log-space errors of Nielsen et al. 2015 and the neural-BRDF papers). 0 for f = g."""
    f = np.asarray(f, dtype=np.float64)
    g = np.asarray(g, dtype=np.float64)
    c = np.clip(np.asarray(wi, dtype=np.float64)[..., 2], 0.0, None).reshape(-1, 1)
    f = f.reshape(c.shape[0], -1)
    g = g.reshape(c.shape[0], -1)
    ok = np.isfinite(f) & np.isfinite(g)
    d = np.abs(np.log((np.clip(np.where(ok, f, 0.0), 0, None) * c + eps) /
                      (np.clip(np.where(ok, g, 0.0), 0, None) * c + eps)))
    n = int(ok.sum())
    return float(np.sum(np.where(ok, d, 0.0)) / n) if n else float("inf")
