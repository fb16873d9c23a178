"""Error metrics and physical plausibility checks for BRDFs (functions of direction pairs or MERL tables)."""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from .geometry import inplane_to_dirs, sph_to_vec

Array = NDArray[np.float64]
BRDF = Callable[[Array, Array], ArrayLike]

__all__ = ["hemisphere_quadrature", "directional_albedo", "reciprocity_error"]


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


def directional_albedo(f: BRDF, theta_i: ArrayLike, n_theta: int = 128, n_phi: int = 256) -> Array:
    """Directional albedo a(theta_i) = integral of f(wi, wo) cos theta_o d wo, shape (len(theta_i), C).

    ``theta_i`` in radians; ``f(wi, wo) -> (N, C)`` vectorised. A passive, energy-conserving BRDF has a <= 1.
    """
    ti = np.atleast_1d(np.asarray(theta_i, dtype=np.float64))
    wo, w = hemisphere_quadrature(n_theta, n_phi)
    out = []
    for t in ti:  # one vectorised hemisphere integral per incidence
        wi, _ = inplane_to_dirs(t, 0.0)
        v = np.asarray(f(np.broadcast_to(wi, wo.shape), wo), dtype=np.float64).reshape(wo.shape[0], -1)
        out.append(w @ v)
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
