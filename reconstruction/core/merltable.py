"""The MERL table (Matusik et al. 2003) in memory: its layout, lookup and tabulation (files: formats/merl.py).

A table in memory is a float64 array ``f`` of shape (3, 90, 90, 180) holding the BRDF f_r in 1/sr, indexed
``[channel, i_theta_h, j_theta_d, k_phi_d]``; NaN marks an invalid (unmeasured or below-horizon) cell.
On disk (see ../shared/reference/merl-format.md): an int32 header ``90 90 180``, then all red, all green,
all blue as little-endian float64, each divided by its channel scale; invalid cells are stored as -1.

A cell stands for its bin centre: theta_h = ((i + 0.5) / 90)^2 * 90 deg, theta_d = (j + 0.5) deg,
phi_d = (k + 0.5) deg, with phi_h = 0. The grid's indices, angles, directions and cosines are in
:mod:`reconstruction.core.merlgrid`.
"""

from __future__ import annotations

import os
from collections.abc import Callable

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.core.geometry import dirs_from_half_diff, half_diff_from_dirs
from reconstruction.core.merlgrid import (
    N_PD,
    N_TD,
    N_TH,
    _cell_dirs,
    _continuous_index,
    _grid_dirs,
    cell_angles,
    phi_d_index,
    theta_d_index,
    theta_h_index,
    valid_mask,
)
from reconstruction.executor import usable_cores

Array = NDArray[np.float64]

SHAPE = (3, N_TH, N_TD, N_PD)
N_CELLS = N_TH * N_TD * N_PD  # 1,458,000
SCALES = np.array([1.0 / 1500.0, 1.15 / 1500.0, 1.66 / 1500.0])  # stored * scale = f_r

__all__ = ["SHAPE", "N_CELLS", "SCALES", "MerlError", "lookup", "brdf_of", "lookup_cells", "tabulate"]


class MerlError(ValueError):
    """A MERL file or table is invalid; the message names the file and the problem."""


# --- lookups ---------------------------------------------------------------------------------------------


def lookup(table: ArrayLike, wi: ArrayLike, wo: ArrayLike, interpolate: bool = False) -> Array:
    """f_r (..., 3) of ``table`` (3, 90, 90, 180) at direction pairs (..., 3).

    ``interpolate=False``: the nearest cell, as the reference reader does. ``interpolate=True``: trilinear
    between bin centres (phi_d wraps with period pi; theta_h and theta_d clamp at the ends), ignoring NaN
    neighbours; NaN only where every neighbour is NaN. Directions below the horizon give NaN.

    Examples
    --------
    >>> t = np.full(SHAPE, 1.0 / np.pi)  # a white Lambertian table
    >>> from reconstruction.core.geometry import inplane_to_dirs
    >>> wi, wo = inplane_to_dirs(np.radians([30.0, 60.0]), np.radians([10.0, -20.0]))
    >>> (lookup(t, wi, wo) * np.pi).round(12).tolist()
    [[1.0, 1.0, 1.0], [1.0, 1.0, 1.0]]
    """
    t = np.asarray(table)
    if t.dtype not in (np.float32, np.float64):  # float32 tables (sigma) read as they are: no 35 MB copy a call
        t = t.astype(np.float64)
    if t.shape != SHAPE:
        raise MerlError(f"table has shape {t.shape}, expected {SHAPE}")
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    shape = np.broadcast_shapes(wi.shape, wo.shape)
    idx, w = lookup_cells(np.broadcast_to(wi, shape).reshape(-1, 3), np.broadcast_to(wo, shape).reshape(-1, 3),
                          interpolate)
    # (3, N, K) the cells' values; a table that is not one block (a grey table broadcast to three channels) read
    # channel by channel, not copied whole
    v = (t.reshape(3, -1)[:, idx] if t.flags.c_contiguous
         else np.stack([t[c].reshape(-1)[idx] for c in range(3)])).astype(np.float64, copy=False)
    ok = np.isfinite(v)
    w = w[None] * ok  # NaN neighbours ignored
    acc = np.sum(w * np.where(ok, v, 0.0), axis=-1)
    wsum = np.sum(w, axis=-1)
    out = np.divide(acc, wsum, out=np.full_like(acc, np.nan), where=wsum > 1e-12)  # NaN below the horizon
    return out.T.reshape(shape[:-1] + (3,))


def brdf_of(table: ArrayLike, interpolate: bool = True) -> Callable[[Array, Array], Array]:
    """The table as a vectorised BRDF ``f(wi, wo) -> (N, 3)`` (1/sr), 0 where it has no value.

    ``interpolate=False`` reads the nearest cell, as renderers that load MERL files do.

    Examples
    --------
    >>> f = brdf_of(np.full(SHAPE, 0.25))
    >>> from reconstruction.core.geometry import inplane_to_dirs
    >>> wi, wo = inplane_to_dirs(np.radians([30.0]), np.radians([-70.0]))
    >>> f(wi, wo).round(12).tolist()
    [[0.25, 0.25, 0.25]]
    """
    t = np.asarray(table, dtype=np.float64)

    def f(wi: Array, wo: Array) -> Array:
        return np.nan_to_num(lookup(t, wi, wo, interpolate=interpolate), nan=0.0)

    # what the renderer needs to render the table as one sparse product (reconstruction.core.render): the table,
    # and each pair's cells and weights, the same lookup as ``f``
    f.table = t  # type: ignore[attr-defined]
    f.table_cells = lambda wi, wo: lookup_cells(wi, wo, interpolate)  # type: ignore[attr-defined]
    f.table_lookup = "merl-interpolated" if interpolate else "merl-nearest"  # type: ignore[attr-defined]
    return f


def lookup_cells(wi: ArrayLike, wo: ArrayLike, interpolate: bool = True) -> tuple[NDArray[np.intp], Array]:
    """The cells and weights of :func:`lookup` at direction pairs (N, 3): flat indices into a channel of the
    table ((90, 90, 180) raveled) and their weights, both (N, 8) (trilinear; (N, 1) and weight 1 for the
    nearest cell). :func:`lookup` is sum(w t[idx]) / sum(w) over the finite cells; pairs below the horizon have
    weight 0.

    Examples
    --------
    >>> from reconstruction.core.merlgrid import cell_to_dirs
    >>> wi, wo = cell_to_dirs(np.array([10]), np.array([30]), np.array([90]))  # a bin centre: its own cell
    >>> idx, w = lookup_cells(wi, wo)
    >>> idx.shape, float(w.sum().round(12)), int(idx[0, np.argmax(w[0])]) == (10 * 90 + 30) * 180 + 90
    ((1, 8), 1.0, True)
    """
    wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
    wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
    th, _, td, pd = half_diff_from_dirs(wi, wo)
    above = ((wi[:, 2] > 0) & (wo[:, 2] > 0)).astype(np.float64)
    if not interpolate:
        idx = (theta_h_index(th) * N_TD + theta_d_index(td)) * N_PD + phi_d_index(pd)
        return idx[:, None], above[:, None]
    xh, xd, xp = _continuous_index(th, td, pd)
    xh = np.clip(xh, 0.0, N_TH - 1.0)
    xd = np.clip(xd, 0.0, N_TD - 1.0)
    ih = np.minimum(np.floor(xh).astype(np.intp), N_TH - 2)
    idd = np.minimum(np.floor(xd).astype(np.intp), N_TD - 2)
    ip = np.floor(xp).astype(np.intp)  # in [-1, 179]
    fh, fd, fp = (x[:, None] for x in (xh - ih, xd - idd, xp - ip))
    a, b, c = np.array([[0, 0, 0, 0, 1, 1, 1, 1], [0, 0, 1, 1, 0, 0, 1, 1], [0, 1, 0, 1, 0, 1, 0, 1]])  # corners
    idx = ((ih[:, None] + a) * N_TD + idd[:, None] + b) * N_PD + (ip[:, None] + c) % N_PD
    w = np.where(a, fh, 1.0 - fh) * np.where(b, fd, 1.0 - fd) * np.where(c, fp, 1.0 - fp) * above[:, None]
    return idx, w


# --- tabulation ------------------------------------------------------------------------------------------


def _as_rgb(v: ArrayLike, n: int) -> Array:
    v = np.asarray(v, dtype=np.float64)
    if v.ndim == 1:
        v = v[:, None]
    if v.shape != (n, 1) and v.shape != (n, 3):
        raise MerlError(f"the BRDF function returned shape {v.shape}, expected ({n}, 1) or ({n}, 3)")
    return np.broadcast_to(v, (n, 3))


def _threads() -> int:
    """Threads for a tabulation: the cores this process may use, at most 4 (numpy releases the GIL in the
    vectorised work of each chunk; ``GONIO_THREADS`` overrides)."""
    env = os.environ.get("GONIO_THREADS", "")
    if env.isdigit() and int(env) > 0:
        return int(env)
    return max(1, min(4, usable_cores()))


def _eval(f: Callable[[Array, Array], ArrayLike], wi: Array, wo: Array, chunk: int) -> Array:
    """f at flat direction pairs (M, 3) -> (M, 3), in chunks that bound memory (each chunk vectorised), the
    chunks spread over :func:`_threads` threads (``f`` must not keep state between calls)."""
    out = np.empty((wi.shape[0], 3))

    def one(s: int) -> None:
        out[s:s + chunk] = _as_rgb(f(wi[s:s + chunk], wo[s:s + chunk]), min(chunk, wi.shape[0] - s))

    _map_chunks(one, range(0, wi.shape[0], chunk))
    return out


def _map_chunks(one: Callable[[int], None], starts: range) -> None:
    """``one(s)`` for every chunk start, spread over :func:`_threads` threads (numpy releases the GIL)."""
    n = min(_threads(), len(starts))
    if n <= 1:
        for s in starts:
            one(s)
        return
    from concurrent.futures import ThreadPoolExecutor

    with ThreadPoolExecutor(max_workers=n) as ex:
        list(ex.map(one, starts))  # re-raises the first exception of any chunk


def _cell_average(f: Callable[[Array, Array], ArrayLike], cells: NDArray[np.intp], ns: tuple[int, int, int],
                  chunk: int) -> Array:
    """Measure-weighted average of f over each cell (M, 3 indices) from nh x nd x np stratified sub-samples.

    Sub-samples are uniform in (sqrt theta_h, theta_d, phi_d) and weighted by the measure of the direction
    pairs they stand for, sin theta_h (d theta_h / du) sin theta_d cos theta_d; sub-samples below the horizon
    get no weight (a renderer never asks for them), so a constant BRDF tabulates to itself. Chunks of cells are
    spread over :func:`_threads` threads, as :func:`_eval`'s (``f`` must not keep state between calls).
    """
    oh = (np.arange(ns[0]) + 0.5) / ns[0]
    od = (np.arange(ns[1]) + 0.5) / ns[1]
    op = (np.arange(ns[2]) + 0.5) / ns[2]
    oh, od, op = (x.ravel() for x in np.meshgrid(oh, od, op, indexing="ij"))
    n_sub = oh.size
    per_chunk = max(1, chunk // n_sub)
    vals = np.empty((cells.shape[0], 3))

    def one(s: int) -> None:  # a chunk of cells, vectorised over cells x sub-samples
        c = cells[s:s + per_chunk]
        u = (c[:, 0:1] + oh[None, :]) / N_TH  # sqrt(theta_h / (pi/2))
        th = u * u * (np.pi / 2)
        td = (c[:, 1:2] + od[None, :]) / N_TD * (np.pi / 2)
        pd = (c[:, 2:3] + op[None, :]) / N_PD * np.pi
        wi, wo = dirs_from_half_diff(th, np.zeros_like(th), td, pd)
        up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
        w = np.sin(th) * u * np.sin(td) * np.cos(td) * up
        fv = _as_rgb(f(wi.reshape(-1, 3), wo.reshape(-1, 3)), c.shape[0] * n_sub).reshape(c.shape[0], n_sub, 3)
        fv = np.where(up[..., None], fv, 0.0)
        wsum = w.sum(axis=1)
        vals[s:s + per_chunk] = np.einsum("cs,csk->ck", w, fv) / np.maximum(wsum, 1e-300)[:, None]

    _map_chunks(one, range(0, cells.shape[0], per_chunk))
    return vals


def _edge_curvature(f: Callable[[Array, Array], ArrayLike], centre: Array, axis: int, chunk: int) -> Array:
    """|mean of f at a cell's two edges along ``axis`` - f at its centre|, (90, 90, 180, 3).

    This second difference is what the centre value misses of the cell average (it is 0 where f is linear
    across the cell). Where an edge is below the horizon, the other edge's difference is used.
    """
    th, td, pd = (a.ravel() for a in cell_angles())
    n = (N_TH, N_TD, N_PD)[axis]
    e = np.arange(n + 1) / n
    edges = [e * e * (np.pi / 2), e * (np.pi / 2), e * np.pi][axis]
    grid = [th, td, pd]
    grid[axis] = edges
    wi, wo = _grid_dirs(*grid)
    up = (wi[..., 2] > 0) & (wo[..., 2] > 0)
    ev = _eval(f, wi.reshape(-1, 3), wo.reshape(-1, 3), chunk).reshape(up.shape + (3,))
    ev[~up] = np.nan
    lo = ev[(slice(None),) * axis + (slice(0, n),)]
    hi = ev[(slice(None),) * axis + (slice(1, n + 1),)]
    mid = np.where(np.isnan(lo), hi, np.where(np.isnan(hi), lo, 0.5 * (lo + hi)))
    return np.abs(mid - centre)


def tabulate(
    f: Callable[[Array, Array], ArrayLike],
    supersample: tuple[int, int, int] | int | str | None = None,
    chunk_cells: int = 200_000,
    adaptive_rtol: float = 0.02,
    adaptive_n: tuple[int, int, int] = (8, 4, 4),
) -> Array:
    """Fill a (3, 90, 90, 180) table from a vectorised BRDF ``f(wi, wo) -> (N, 1 | 3)`` (1/sr).

    ``supersample=None``: the value at each cell's bin centre.
    ``supersample=(nh, nd, np)`` (or one int for all three): every cell holds the average of f over the cell
    (see :func:`_cell_average`), so a lobe narrower than a cell keeps its energy.
    ``supersample="adaptive"``: f is also evaluated on the cell edges; a cell is averaged with
    ``adaptive_n`` sub-samples along each axis where the mean of its two edge values differs from its centre
    value by more than ``adaptive_rtol`` (relative: f is far from linear across the cell, as inside a lobe
    narrower than a few cells), and keeps its centre value elsewhere: cell averages where they matter
    (sharp lobes) at a fraction of the cost.
    Cells whose bin-centre directions lie below the horizon are NaN.

    Examples
    --------
    >>> t = tabulate(lambda wi, wo: np.full((len(wi), 3), 0.5 / np.pi))
    >>> t.shape, float(np.nanmax(t) * np.pi), int(np.isnan(t).sum() // 3)  # NaN below the horizon
    ((3, 90, 90, 180), 0.5, 361784)
    """
    valid = valid_mask()
    wi, wo = _cell_dirs()
    if supersample is None or supersample == "adaptive":
        # f is evaluated at every cell (below-horizon results are discarded): cheaper than gathering valid cells
        centre = _eval(f, wi.reshape(-1, 3), wo.reshape(-1, 3), chunk_cells).reshape(wi.shape)
        centre[~valid] = np.nan
    if supersample is None:
        return np.ascontiguousarray(np.moveaxis(centre, -1, 0))
    if supersample == "adaptive":
        scale = np.nanmax(np.abs(centre)) if np.isfinite(centre).any() else 0.0
        need = []
        for axis in range(3):
            var = _edge_curvature(f, centre, axis, chunk_cells)
            tol = adaptive_rtol * np.abs(centre) + 1e-9 * scale
            need.append(np.any(var > tol, axis=-1) & valid)
        vals = centre.copy()
        flags = need[0].astype(np.int8) + 2 * need[1] + 4 * need[2]
        for pattern in range(1, 8):  # cells grouped by which axes need sub-samples
            cells = np.argwhere(flags == pattern)
            if cells.size == 0:
                continue
            ns = tuple(adaptive_n[a] if pattern >> a & 1 else 1 for a in range(3))
            vals[tuple(cells.T)] = _cell_average(f, cells, ns, chunk_cells)  # type: ignore[arg-type]
        return np.ascontiguousarray(np.moveaxis(vals, -1, 0))
    if isinstance(supersample, str):
        raise MerlError(f"supersample must be None, 'adaptive', an int or three ints, got {supersample!r}")
    ns = (supersample,) * 3 if isinstance(supersample, int) else tuple(supersample)
    if len(ns) != 3 or min(ns) < 1:
        raise MerlError(f"supersample must be a positive int or three positive ints, got {supersample!r}")
    out = np.full(SHAPE, np.nan)
    out[:, valid] = _cell_average(f, np.argwhere(valid), ns, chunk_cells).T  # type: ignore[arg-type]
    return out


def tabulate_reciprocal(g: Callable[[Array, Array], ArrayLike]) -> Array:
    """The bin-centre table of 0.5 (g(wi, wo) + g(wo, wi)) from one evaluation of ``g`` per cell, for a ``g``
    symmetric under reflection in the plane of incidence: the swapped pair of cell phi_d is the mirror image of
    cell pi - phi_d (bin k of 180 <-> bin 179 - k), so the reciprocal table is the average of g's table and
    its phi_d-reversed self. (3, 90, 90, 180), NaN below the horizon as :func:`tabulate`."""
    t = tabulate(g)
    return 0.5 * (t + t[..., ::-1])


def average_theta_h_cells(f: Callable[[Array, Array], ArrayLike], table: ArrayLike, theta_h_max: float,
                          n: int = 16, chunk_cells: int = 200_000) -> tuple[Array, int]:
    """``table`` with its cells below ``theta_h_max`` (radians) replaced by f's cell averages over theta_h.

    For a lobe narrower than the table's cells near the mirror direction (a fitted ggx alpha of 1e-3 spans the
    first two theta_h cells): ``n`` sub-samples per cell in theta_h (one in theta_d and phi_d, where such a lobe
    hardly changes), weighted as :func:`tabulate`'s cell averages. Returns (table, number of theta_h rows).
    """
    out = np.array(table, dtype=np.float64, copy=True)
    rows = int(min(N_TH, theta_h_index(theta_h_max) + 1))
    valid = valid_mask()
    cells = np.argwhere(valid[:rows])
    if cells.size:
        out[:, cells[:, 0], cells[:, 1], cells[:, 2]] = _cell_average(f, cells, (n, 1, 1), chunk_cells).T
    return out, rows
