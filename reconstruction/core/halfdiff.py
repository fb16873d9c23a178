"""BRDFs given by the half-diff angles on the MERL table's grid, without direction vectors.

A lobe such as a microfacet term is a function of theta_h, theta_d, cos theta_i and cos theta_o; on the table's
grid those cosines have a closed form (phi_h = 0, as :func:`reconstruction.core.geometry.dirs_from_half_diff`), so its
table rows and their theta_h cell averages (:func:`~reconstruction.core.merltable.average_theta_h_cells`) are computed
at a fraction of the cost of evaluating direction pairs.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numpy.typing import NDArray

from reconstruction.core.merlgrid import N_PD, N_TD, N_TH, cell_angles, theta_h_index
from reconstruction.core.models import Lambert, Lobe, Microfacet, Retro

Array = NDArray[np.float64]

__all__ = ["average_theta_h_half_diff", "lobe_half_diff"]


def average_theta_h_half_diff(f_hd: Callable[[Array, Array, Array, Array], Array], theta_h_max: float, n: int = 8,
                              block_rows: int = 2) -> tuple[int, Array, NDArray[np.bool_]]:
    """:func:`reconstruction.core.merltable.average_theta_h_cells` for a function of the half-diff angles:
    ``f_hd(theta_h, theta_d, cos theta_i, cos theta_o)`` (radians; broadcast shapes, 0 below the horizon) -> one value
    per point, e.g. a lobe's shape.

    The same ``n`` sub-samples and weights per cell, with cos theta_i and cos theta_o in closed form (phi_h = 0, as
    :func:`reconstruction.core.geometry.dirs_from_half_diff`), computed ``block_rows`` theta_h rows at a time (small
    temporaries). Returns (rows, averages (rows, 90, 180), covered (rows, 90, 180): the cell has a sub-sample
    above the horizon; an uncovered cell averages to 0).
    """
    rows = int(min(N_TH, theta_h_index(theta_h_max) + 1))
    _, td, pd = cell_angles()
    sc = (np.sin(td) * np.cos(pd))[..., None]
    td = td[..., None]
    ctd = np.cos(td)
    out = np.empty((rows, N_TD, N_PD))
    covered = np.empty((rows, N_TD, N_PD), dtype=bool)
    for r0 in range(0, rows, block_rows):
        r = np.arange(r0, min(rows, r0 + block_rows))
        u = (r[:, None] + (np.arange(n)[None, :] + 0.5) / n) / N_TH  # sqrt(theta_h / (pi/2))
        th = (u * u * (np.pi / 2))[:, None, None, :]
        ci = np.cos(th) * ctd - np.sin(th) * sc
        co = (2.0 * ctd) * np.cos(th) - ci
        w = np.sin(th) * u[:, None, None, :] * ((ci > 0) & (co > 0))  # the measure, as _cell_average's
        wsum = w.sum(axis=-1)
        out[r] = np.einsum("hdps,hdps->hdp", w, f_hd(th, td, ci, co)) / np.maximum(wsum, 1e-300)
        covered[r] = wsum > 0
    return rows, out, covered


def lobe_half_diff(lobe: Lobe, theta_h: Array, theta_d: Array, cos_i: Array, cos_o: Array) -> Array | None:
    """A lobe's shape (before its colour) from the half-diff angles (radians) and cos theta_i, cos theta_o
    (broadcast against each other; :func:`reconstruction.core.merlgrid.cell_cosines` on the table's grid) for
    lambert, the microfacet lobes (ggx, beckmann) and retro (wi . wo = cos 2 theta_d); None for any other lobe."""
    if isinstance(lobe, Microfacet):
        return lobe.shape_half_diff(theta_h, theta_d, cos_i, cos_o)
    if type(lobe) is Lambert:
        return np.where((cos_i > 0) & (cos_o > 0), 1.0 / np.pi, 0.0)
    if type(lobe) is Retro:
        dot = np.cos(2.0 * np.asarray(theta_d, dtype=np.float64))
        return np.where((cos_i > 0) & (cos_o > 0),
                        (lobe.exponent + 2.0) / (2.0 * np.pi) * np.maximum(dot, 0.0) ** lobe.exponent, 0.0)
    return None
