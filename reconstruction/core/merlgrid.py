"""The MERL table's grid (Matusik et al. 2003): its cells' indices, bin-centre angles, directions and cosines.

A cell ``[i_theta_h, j_theta_d, k_phi_d]`` of a (90, 90, 180) table stands for its bin centre:
theta_h = ((i + 0.5) / 90)^2 * 90 deg, theta_d = (j + 0.5) deg, phi_d = (k + 0.5) deg, with phi_h = 0.
The table in memory (layout, lookup, tabulation) is :mod:`reconstruction.core.merltable`; its file,
:mod:`reconstruction.formats.merl`.
"""

from __future__ import annotations

from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.core.geometry import dirs_from_half_diff, half_diff_from_dirs

Array = NDArray[np.float64]

N_TH, N_TD, N_PD = 90, 90, 180

__all__ = ["N_TH", "N_TD", "N_PD", "theta_h_index", "theta_d_index", "phi_d_index", "cell_angles", "cell_to_dirs",
           "dirs_to_cell", "valid_mask", "cell_cosines"]


# --- index functions (the reference reader's) ------------------------------------------------------------


def theta_h_index(theta_h: ArrayLike) -> NDArray[np.intp]:
    """Cell index of theta_h (radians): int(sqrt(theta_h / (pi/2)) * 90), 0 for theta_h <= 0, in [0, 89].

    Examples
    --------
    >>> theta_h_index(np.radians([0.0, 1.0, 45.0, 89.9])).tolist()
    [0, 9, 63, 89]
    """
    th = np.asarray(theta_h, dtype=np.float64)
    u = np.sqrt(np.maximum(th, 0.0) / (np.pi / 2)) * N_TH
    return np.clip(np.floor(u), 0, N_TH - 1).astype(np.intp)


def theta_d_index(theta_d: ArrayLike) -> NDArray[np.intp]:
    """Cell index of theta_d (radians): int(theta_d / (pi/2) * 90) in [0, 89].

    Examples
    --------
    >>> theta_d_index(np.radians([0.0, 30.5, 89.9])).tolist()
    [0, 30, 89]
    """
    td = np.asarray(theta_d, dtype=np.float64)
    return np.clip(np.floor(td / (np.pi / 2) * N_TD), 0, N_TD - 1).astype(np.intp)


def phi_d_index(phi_d: ArrayLike) -> NDArray[np.intp]:
    """Cell index of phi_d (radians): fold phi_d < 0 by +pi, then int(phi_d / pi * 180) in [0, 179].

    Examples
    --------
    >>> phi_d_index(np.radians([0.0, 90.0, -90.0, 179.9])).tolist()  # phi_d < 0 folds by +180 deg
    [0, 90, 90, 179]
    """
    pd = np.asarray(phi_d, dtype=np.float64)
    pd = np.where(pd < 0, pd + np.pi, pd)
    return np.clip(np.floor(pd / np.pi * N_PD), 0, N_PD - 1).astype(np.intp)


def _continuous_index(theta_h: Array, theta_d: Array, phi_d: Array) -> tuple[Array, Array, Array]:
    """Fractional cell coordinates whose integer values are bin centres (x = index + 0.5 at the centre)."""
    xh = np.sqrt(np.maximum(theta_h, 0.0) / (np.pi / 2)) * N_TH - 0.5
    xd = theta_d / (np.pi / 2) * N_TD - 0.5
    pd = np.mod(phi_d, np.pi)  # reciprocity: phi_d and phi_d + pi are the same cell
    xp = pd / np.pi * N_PD - 0.5
    return xh, xd, xp


@lru_cache(maxsize=1)
def cell_angles() -> tuple[Array, Array, Array]:
    """Bin-centre angles (theta_h, theta_d, phi_d) in radians, each broadcastable to (90, 90, 180).

    Examples
    --------
    >>> th, td, pd = cell_angles()
    >>> th.shape, td.shape, pd.shape
    ((90, 1, 1), (1, 90, 1), (1, 1, 180))
    >>> round(float(np.degrees(td[0, 0, 0])), 6), round(float(np.degrees(pd[0, 0, 1])), 6)
    (0.5, 1.5)
    """
    i = np.arange(N_TH, dtype=np.float64)
    th = ((i + 0.5) / N_TH) ** 2 * (np.pi / 2)
    td = (np.arange(N_TD) + 0.5) / N_TD * (np.pi / 2)
    pd = (np.arange(N_PD) + 0.5) / N_PD * np.pi
    return th[:, None, None], td[None, :, None], pd[None, None, :]


def cell_to_dirs(i: ArrayLike, j: ArrayLike, k: ArrayLike) -> tuple[Array, Array]:
    """Direction pairs (wi, wo), (..., 3), standing for cells (i, j, k): their bin centres with phi_h = 0.

    Examples
    --------
    >>> wi, wo = cell_to_dirs(0, 30, 90)
    >>> wi.shape, bool(wi[2] > 0 and wo[2] > 0)
    ((3,), True)
    """
    i = np.asarray(i, dtype=np.float64)
    j = np.asarray(j, dtype=np.float64)
    k = np.asarray(k, dtype=np.float64)
    th = ((i + 0.5) / N_TH) ** 2 * (np.pi / 2)
    td = (j + 0.5) / N_TD * (np.pi / 2)
    pd = (k + 0.5) / N_PD * np.pi
    return dirs_from_half_diff(th, np.zeros_like(th), td, pd)


def dirs_to_cell(wi: ArrayLike, wo: ArrayLike) -> tuple[NDArray[np.intp], NDArray[np.intp], NDArray[np.intp]]:
    """Cell indices (i, j, k) of direction pairs (..., 3), with the reference reader's index functions.

    Examples
    --------
    >>> wi, wo = cell_to_dirs(10, 30, 90)
    >>> [int(x) for x in dirs_to_cell(wi, wo)]
    [10, 30, 90]
    """
    th, _, td, pd = half_diff_from_dirs(wi, wo)
    return theta_h_index(th), theta_d_index(td), phi_d_index(pd)


def _grid_dirs(th: Array, td: Array, pd: Array) -> tuple[Array, Array]:
    """Direction pairs (len(th), len(td), len(pd), 3) on a grid of 1-D angle arrays (radians), phi_h = 0.

    Separable: d depends on (theta_d, phi_d) only, and wi is d rotated by theta_h about y.
    """
    th = np.asarray(th, dtype=np.float64).reshape(-1, 1, 1, 1)
    td = np.asarray(td, dtype=np.float64).reshape(1, -1, 1)
    pd = np.asarray(pd, dtype=np.float64).reshape(1, 1, -1)
    st, ct = np.sin(td), np.cos(td)
    dx, dy, dz = st * np.cos(pd), np.broadcast_to(st * np.sin(pd), (1, td.shape[1], pd.shape[2])), ct
    c, s = np.cos(th), np.sin(th)
    shape = (th.shape[0], td.shape[1], pd.shape[2], 3)
    wi = np.empty(shape)
    wi[..., 0] = c[..., 0] * dx + s[..., 0] * dz
    wi[..., 1] = dy
    wi[..., 2] = -s[..., 0] * dx + c[..., 0] * dz
    # wo = 2 (wi . h) h - wi with h = (sin th, 0, cos th) and wi . h = d_z = cos theta_d
    h = np.concatenate([s, np.zeros_like(s), c], axis=-1)
    wo = 2.0 * np.broadcast_to(dz, (1,) + dz.shape[1:])[..., None] * h - wi
    return wi, wo


@lru_cache(maxsize=1)
def _cell_dirs() -> tuple[Array, Array]:
    """Bin-centre direction pairs (90, 90, 180, 3), read-only and cached."""
    th, td, pd = cell_angles()
    wi, wo = _grid_dirs(th.ravel(), td.ravel(), pd.ravel())
    wi.setflags(write=False)
    wo.setflags(write=False)
    return wi, wo


@lru_cache(maxsize=1)
def cell_cosines() -> tuple[Array, Array]:
    """cos theta_i and cos theta_o (90, 90, 180) at the bin centres, from the angles in closed form (phi_h = 0, as
    :func:`reconstruction.core.geometry.dirs_from_half_diff`): the z components of :func:`_cell_dirs`' directions,
    bit for bit (tests/test_merl.py), without the 70 MB of direction vectors. Read-only and cached."""
    th, td, pd = cell_angles()
    ctd = np.cos(td)
    ci = np.cos(th) * ctd - np.sin(th) * (np.sin(td) * np.cos(pd))
    co = (2.0 * ctd) * np.cos(th) - ci
    ci.setflags(write=False)
    co.setflags(write=False)
    return ci, co


@lru_cache(maxsize=1)
def _valid_mask() -> NDArray[np.bool_]:
    ci, co = cell_cosines()
    m = (ci > 0) & (co > 0)
    m.setflags(write=False)
    return m


def valid_mask() -> NDArray[np.bool_]:
    """(90, 90, 180) bool: cells whose bin-centre directions both lie above the horizon (read-only, cached).

    Examples
    --------
    >>> m = valid_mask()
    >>> m.shape, bool(m[0, 0, 0]), bool(m[89, 89, 0])
    ((90, 90, 180), True, False)
    """
    return _valid_mask()
