"""The energy of a lobe narrower than the MERL table's cells: the table's first theta_h rows renormalised, theta_d row
by theta_d row, to the BRDF's own directional albedo as the two kinds of table readers see them.

A lobe such as ggx alpha 1e-3 lies inside the first few theta_h cells (the cell at theta_h = 0 spans 0.011 deg), so
the table holds it as cell averages (:func:`reconstruction.core.merltable.average_theta_h_cells`). Two readers see
different
energies in them:

* a reader that snaps to cells (the MERL reference code, renderers; ``merltable.lookup(interpolate=False)``) sees the
  cell averages' energy, the lobe's own, up to the sub-sampling of the averages;
* a reader that interpolates between bin centres (``interpolate=True``: the plausibility check, the previews, the HTML
  report) sees more: theta_h is binned quadratically, so the measure sin(theta_h) d theta_h grows as u^3 across a cell
  (u = sqrt(theta_h / 90 deg)) and its hat functions weigh the first cells more than their own measure (the first,
  clamped below its centre, 1.5 times). +7 % for alpha 1e-3, +1.5 % for alpha 5e-3; no non-negative table is exact
  for both readers when the lobe lies in the first few cells.

Towards grazing incidence both readers overshoot further: at the mirror direction f ~ 1 / cos^2(theta_d), and a
reading between two theta_d bin centres averages them (+0.7 % half way at theta_d = 80 deg, +3 % at 85 deg).

:func:`renormalise` measures this on the table itself. For incidences theta_i every 0.5 deg (every theta_d bin centre
and edge) it integrates over the half vectors of the rows that hold the lobe (Gauss-Legendre on every half row in u,
midpoint rule in phi_h): each reader's reading of those rows, theta_d row by theta_d row (sparse matrices of the
geometry alone, built once per number of rows and kept in the disk cache), and the BRDF's own albedo over the same
half vectors, weighted as each reader weighs those rows. A theta_d row is then scaled so that

* the snapping reader sees the BRDF's albedo (the format's meaning: what a renderer shows),
* unless the interpolating reader would then see more than the surface receives (albedo 1) and more than the BRDF
  reflects (its own albedo, over the whole hemisphere): then just so much less that it does not,

taking the smallest such scale among the incidences up to 85 deg the row contributes to, per channel (its shape in
theta_h and phi_d is kept; the rows only grazing incidences reach keep their cell averages). So a physical material
gives a plausible table, and an implausible one stays implausible: the interpolating reader still sees at least the
BRDF's own albedo.
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.cache import cached_arrays
from reconstruction.core.geometry import half_diff_from_dirs, inplane_to_dirs
from reconstruction.core.merlgrid import (
    N_PD,
    N_TD,
    N_TH,
    _continuous_index,
    phi_d_index,
    theta_d_index,
    theta_h_index,
    valid_mask,
)
from reconstruction.core.merltable import SHAPE
from reconstruction.core.metrics import halfvector_albedo

Array = NDArray[np.float64]

__all__ = ["renormalise", "sharp_rows", "INCIDENCES_DEG", "SCALE_RANGE", "CONTRIBUTION_MIN", "DESCRIPTION"]

#: What the rows hold after :func:`renormalise`, for the report.
DESCRIPTION = ("those rows scaled per theta_d row to the lobe's albedo: exact for a reader that snaps to cells, at "
               "most the larger of 1 and the BRDF's albedo for one that interpolates (reconstruction.core.sharprows)")

#: Incidences (deg) at which the rows' energy is compared: every theta_d bin centre and edge of the table.
INCIDENCES_DEG = np.arange(0.0, 89.75, 0.5)
#: A row's scale is kept within this range: the renormalisation corrects how a table holds a lobe, not the lobe.
SCALE_RANGE = (0.25, 4.0)
#: A theta_d row counts among an incidence's contributors when it gives at least this fraction of either reading.
CONTRIBUTION_MIN = 0.05
#: Incidences (deg) up to this one set the rows' scales (and the report's figures), as far as the plausibility check
#: goes. Beyond, a theta_d row cannot hold a sharp lobe at all (f ~ 1 / cos^2 theta_d changes 4-fold across row 89,
#: and the readers see 1.2-1.9 times its energy there): the rows only they reach keep their cell averages.
CHECKED_MAX_DEG = 85.0
_N_GAUSS_TABLE = 3  # per half row in u: both readings are polynomial in u there (times u^3), up to theta_d / phi_d
_N_PHI = 32  # midpoint rule in phi_h (periodic) of the table's readings
_N_PHI_OWN = 8  # and of the BRDF's: a lobe near theta_h = 0 changes with phi_h as its first few harmonics
_OWN_SUB = 16  # sub-intervals per row (uniform in u, Gauss-Legendre 2 in each) of the BRDF's own integral: fine
_N_GAUSS_OWN = 2  # near theta_h = 0 (a lobe of alpha 1e-5 rad spans 4 of them) and at the edge of a plateau
#: Incidences (deg) of the BRDF's own integrals, interpolated linearly to :data:`INCIDENCES_DEG`: they change slowly
#: with theta_i, fastest towards grazing.
_OWN_INCIDENCES_DEG = np.concatenate([np.arange(0.0, 80.0, 2.0), np.arange(80.0, 89.75, 0.5)])
_TOTAL_QUADRATURE = (24, 4, 32)  # the BRDF's albedo over the whole hemisphere: metrics.halfvector_albedo's sizes


def sharp_rows(theta_h_max: float) -> int:
    """The number of theta_h rows that :func:`renormalise` scales for a lobe averaged below ``theta_h_max`` (radians):
    those :func:`reconstruction.core.merltable.average_theta_h_cells` averages (at most 89)."""
    return int(min(N_TH - 1, theta_h_index(theta_h_max) + 1))


def _gauss_panels(edges: Array, n: int) -> tuple[Array, Array]:
    """Gauss-Legendre nodes and weights of ``n`` points in each panel between consecutive ``edges``."""
    x, wx = np.polynomial.legendre.leggauss(n)
    lo, hi = edges[:-1, None], edges[1:, None]
    return (0.5 * (hi - lo) * (x + 1.0) + lo).ravel(), (0.5 * (hi - lo) * wx).ravel()


def _half_vectors(xe: Array, n_gauss: int) -> tuple[Array, Array, Array]:
    """theta_h nodes (radians), d theta_h weights and the reader's continuous row index x of Gauss-Legendre panels
    between ``xe`` (continuous row indices: x = i at the centre of row i, u = (x + 0.5) / 90)."""
    xq, wx = _gauss_panels(xe, n_gauss)
    u = (xq + 0.5) / N_TH
    return u * u * (np.pi / 2), u * (np.pi / N_TH) * wx, xq  # d theta_h = pi u du, du = dx / 90


def _dirs(theta_h: Array, weight_h: Array, incidences_deg: Array, n_phi: int) -> tuple[Array, Array, Array]:
    """For every incidence (deg) and half vector (theta_h nodes x phi_h midpoints): wi, wo (n_inc, n_h, 3) and the
    weight of f in the albedo integral (d omega_h x 4 (wi . h) x cos theta_o, with ``weight_h`` the theta_h part; 0
    where wo or wi . h is below the horizon)."""
    ph = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    th = np.repeat(theta_h, n_phi)
    w = np.repeat(np.sin(theta_h) * weight_h, n_phi) * (2 * np.pi / n_phi)
    phi = np.tile(ph, theta_h.size)
    h = np.stack([np.sin(th) * np.cos(phi), np.sin(th) * np.sin(phi), np.cos(th)], axis=-1)
    wi, _ = inplane_to_dirs(np.radians(incidences_deg), np.zeros(incidences_deg.size))
    c = wi @ h.T  # (n_inc, n_h)
    wo = 2.0 * c[..., None] * h[None] - wi[:, None, :]
    ok = (c > 0) & (wo[..., 2] > 0)
    return np.broadcast_to(wi[:, None, :], wo.shape), wo, np.where(ok, w[None] * 4.0 * c * wo[..., 2], 0.0)


@lru_cache(maxsize=1)
def _source_key() -> str:
    """The disk cache key of the readers' matrices: this module's source (its grids, incidences and readers)."""
    return hashlib.sha1(Path(__file__).read_bytes()).hexdigest()


@lru_cache(maxsize=4)
def _readers(rows: int) -> tuple[Any, Any]:
    """(interpolating, snapping) sparse matrices (n_inc * 90, rows * 90 * 180): entry ((m, j), cell) is the weight of
    ``cell`` (theta_h row < rows, theta_d row j) in the albedo that reader gives at incidence m, so that
    ``K @ t[c, :rows].ravel()`` is the rows' reading per (incidence, theta_d row). Geometry only (the cells below
    the
    horizon are NaN in every table, and left out as :func:`reconstruction.core.merltable.lookup` leaves them out); kept
    in the
    disk cache (:mod:`reconstruction.cache`)."""
    from scipy import sparse

    arrays = cached_arrays(f"sharprows-{rows}", f"{_source_key()} rows={rows}", lambda: _build_readers(rows))
    shape = (INCIDENCES_DEG.size * N_TD, rows * N_TD * N_PD)
    return (sparse.csr_matrix(tuple(arrays[:3]), shape=shape),  # type: ignore[arg-type]
            sparse.csr_matrix(tuple(arrays[3:]), shape=shape))  # type: ignore[arg-type]


def _build_readers(rows: int) -> tuple[Array, ...]:
    """(data, indices, indptr) of the interpolating then the snapping reader's CSR matrices (:func:`_readers`)."""
    from scipy import sparse

    # half rows: the interpolating reader is linear between bin centres, the snapping one constant within cells
    th, wth, _ = _half_vectors(np.arange(-0.5, rows + 0.25, 0.5), _N_GAUSS_TABLE)
    wi, wo, w = _dirs(th, wth, INCIDENCES_DEG, _N_PHI)
    use = w > 0
    m = np.nonzero(use)[0]
    wi, wo, w = wi[use], wo[use], w[use]  # flat: the half vectors that reflect above the horizon
    thn, _, td, pd = half_diff_from_dirs(wi, wo)
    shape = (INCIDENCES_DEG.size * N_TD, rows * N_TD * N_PD)
    valid = valid_mask()
    out: list[Array] = []

    def csr(r: NDArray[np.intp], i: NDArray[np.intp], j: NDArray[np.intp], k: NDArray[np.intp], v: Array) -> None:
        keep = (i < rows) & (v > 0)
        op = sparse.csr_matrix((v[keep], (r[keep] * N_TD + j[keep], (i[keep] * N_TD + j[keep]) * N_PD + k[keep])),
                               shape=shape)
        op.sum_duplicates()
        out.extend([op.data, op.indices.astype(np.int64), op.indptr.astype(np.int64)])

    xh, xd, xp = _continuous_index(thn, td, pd)  # as merltable.lookup(interpolate=True)
    xh, xd = np.clip(xh, 0.0, N_TH - 1.0), np.clip(xd, 0.0, N_TD - 1.0)
    ih = np.minimum(np.floor(xh).astype(np.intp), N_TH - 2)
    idd = np.minimum(np.floor(xd).astype(np.intp), N_TD - 2)
    ip = np.floor(xp).astype(np.intp)
    fh, fd, fp = xh - ih, xd - idd, xp - ip
    a, b, c = (x.reshape(8, 1) for x in np.unravel_index(np.arange(8), (2, 2, 2)))  # the 8 corners
    i, j, k = ih[None] + a, idd[None] + b, (ip[None] + c) % N_PD
    wc = np.where(a, fh, 1 - fh) * np.where(b, fd, 1 - fd) * np.where(c, fp, 1 - fp) * valid[i, j, k]
    wsum = wc.sum(axis=0)
    wc *= np.divide(w, wsum, out=np.zeros_like(w), where=wsum > 1e-12)[None]
    csr(np.broadcast_to(m[None], i.shape).ravel(), i.ravel(), j.ravel(), k.ravel(), wc.ravel())
    i, j, k = theta_h_index(thn), theta_d_index(td), phi_d_index(pd)  # as merltable.lookup(interpolate=False)
    csr(m, i, j, k, w * valid[i, j, k])
    return tuple(out)


def _own_albedo(f: Callable[[Array, Array], ArrayLike], rows: int) -> tuple[Array, Array, Array]:
    """The BRDF's albedo (3, n_inc) at :data:`INCIDENCES_DEG` over the half vectors of rows < ``rows`` as the
    interpolating reader weighs them (1 up to the centre of row rows - 1, then linearly down to 0 at the centre of row
    ``rows``) and as the snapping one does (1 up to the edge of row rows - 1), and over the whole hemisphere."""
    th, wth, x = _half_vectors(np.linspace(-0.5, rows, int(round((rows + 0.5) * _OWN_SUB)) + 1), _N_GAUSS_OWN)
    ramp, step = np.clip(rows - x, 0.0, 1.0), (x < rows - 0.5).astype(np.float64)
    wi, wo, w = _dirs(th, wth, _OWN_INCIDENCES_DEG, _N_PHI_OWN)
    use = w > 0
    m, h = np.nonzero(use)
    v = np.nan_to_num(np.asarray(f(wi[use], wo[use]), dtype=np.float64).reshape(m.size, -1), nan=0.0)
    v = np.broadcast_to(v, (m.size, 3)) if v.shape[1] == 1 else v
    n_own = _OWN_INCIDENCES_DEG.size

    def per_incidence(weight: Array) -> Array:
        vals = v * (w[use] * weight[h // _N_PHI_OWN])[:, None]
        return np.stack([np.bincount(m, vals[:, c], n_own) for c in range(3)])

    total = halfvector_albedo(f, np.radians(_OWN_INCIDENCES_DEG), *_TOTAL_QUADRATURE)
    total = np.broadcast_to(total, (n_own, 3)).T if total.shape[1] == 1 else total.T
    return tuple(np.stack([np.interp(INCIDENCES_DEG, _OWN_INCIDENCES_DEG, a) for a in arr])  # type: ignore[return-value]
                 for arr in (per_incidence(ramp), per_incidence(step), total))


def renormalise(f: Callable[[Array, Array], ArrayLike], table: ArrayLike, theta_h_max: float
                ) -> tuple[Array, dict[str, Any]]:
    """``table`` (3, 90, 90, 180) with its rows below ``theta_h_max`` (radians; the rows
    :func:`reconstruction.core.merltable.average_theta_h_cells` averages) scaled per theta_d row and channel as the
    module docstring says. Returns (table, info): ``rows``, the scales' range and each reader's largest excess over the
    BRDF's albedo before (``interpolating_excess_before``, ``snapping_excess_before``: reading / BRDF - 1 over
    those rows' half vectors, at incidences up to :data:`CHECKED_MAX_DEG`)."""
    t = np.array(table, dtype=np.float64, copy=True)
    if t.shape != SHAPE:
        raise ValueError(f"table has shape {t.shape}, expected {SHAPE}")
    rows = sharp_rows(theta_h_max)
    interp, snap = _readers(rows)
    sub = np.nan_to_num(t[:, :rows], nan=0.0).reshape(3, -1)
    read_i = np.stack([(interp @ sub[c]).reshape(INCIDENCES_DEG.size, N_TD) for c in range(3)])  # (3, n_inc, 90)
    read_n = np.stack([(snap @ sub[c]).reshape(INCIDENCES_DEG.size, N_TD) for c in range(3)])
    tot_i, tot_n = read_i.sum(axis=-1), read_n.sum(axis=-1)
    own_i, own_n, own_total = _own_albedo(f, rows)
    # the interpolating reader may see up to what the surface receives (1) or the BRDF reflects, whichever is more
    allowed_i = own_i + np.maximum(1.0 - own_total, 0.0)
    tiny = 1e-9 * np.maximum(tot_i.max(axis=-1, keepdims=True), 1e-300)
    ok = (tot_i > tiny) & (tot_n > tiny) & (INCIDENCES_DEG <= CHECKED_MAX_DEG)
    q = np.where(ok, np.minimum(own_n / np.where(ok, tot_n, 1.0), allowed_i / np.where(ok, tot_i, 1.0)), np.inf)
    counts = ok[..., None] & ((read_i >= CONTRIBUTION_MIN * tot_i[..., None])
                              | (read_n >= CONTRIBUTION_MIN * tot_n[..., None]))
    s = np.min(np.where(counts, q[..., None], np.inf), axis=1)  # (3, 90): the tightest incidence of each row
    s = np.where(np.isfinite(s), np.clip(s, *SCALE_RANGE), 1.0)
    t[:, :rows] *= s[:, None, :, None]

    def excess(read: Array, own: Array) -> float:
        return float(np.max(np.where(ok, read / np.maximum(own, 1e-300) - 1.0, -np.inf), initial=-np.inf))

    return t, {"rows": rows, "scale_min": float(s.min()), "scale_max": float(s.max()),
               "interpolating_excess_before": excess(tot_i, own_i), "snapping_excess_before": excess(tot_n, own_n)}
