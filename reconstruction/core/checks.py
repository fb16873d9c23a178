"""The plausibility checks of a written table: finite and non-negative, directional albedo <= 1 (+ tolerance) at
every checked incidence, and the reconstruction's reciprocity. The report's ``checks`` section, ``auto``'s
rejection of a method that reflects more than it receives, and the refusal to write an implausible table (exit 3)
all use these."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.base import Reconstruction
from reconstruction.core import merlgrid, merltable
from reconstruction.core.metrics import directional_albedo, halfvector_albedo, reciprocity_error

Array = NDArray[np.float64]

__all__ = ["ALBEDO_TOLERANCE", "RECIPROCITY_TOLERANCE", "ALBEDO_INCIDENCES_DEG", "checked_albedo", "plausibility",
           "mirror_symmetric"]

ALBEDO_TOLERANCE = 0.01
RECIPROCITY_TOLERANCE = 1e-6
ALBEDO_INCIDENCES_DEG = np.arange(0.0, 86.0, 5.0)


def checked_albedo(f: Callable[[Array, Array], ArrayLike], n_theta: int, n_phi: int, mirror: bool = False
                   ) -> tuple[Array, str]:
    """Directional albedo (len(ALBEDO_INCIDENCES_DEG), C) of the BRDF ``f`` at the checked incidences, and how it
    was integrated: on an ``n_theta`` x ``n_phi`` hemisphere grid, or, when that exceeds 1 + ALBEDO_TOLERANCE, over
    the half vector (a peak narrower than the grid, a mirror-like lobe, aliases on it). With ``mirror`` (``f``
    symmetric about the plane of incidence: :func:`mirror_symmetric` of a table) the grid's half on one side of
    the plane is evaluated, at twice the weight."""
    ti = np.radians(ALBEDO_INCIDENCES_DEG)
    alb = directional_albedo(f, ti, n_theta, n_phi, mirror=mirror)
    if np.all(alb <= 1.0 + ALBEDO_TOLERANCE):
        return alb, f"hemisphere, {n_theta} x {n_phi}"
    return halfvector_albedo(f, ti), "half vector (a peak narrower than the hemisphere grid)"


def mirror_symmetric(table: Array, rtol: float = 1e-12) -> bool:
    """Whether ``table`` (3, 90, 90, 180) reads the same at phi_d and pi - phi_d in every cell (to ``rtol`` of its
    largest value; cells without a value, NaN, left out): then its lookups at a direction and at its mirror image
    about the plane of incidence agree, as an isotropic, reciprocal BRDF's do (fit, microfacet, revolve and
    bivariate tables are; the prior's reduced grid is not exactly, by up to a few percent)."""
    with np.errstate(invalid="ignore"):
        d = np.subtract(table, table[..., ::-1])
        np.abs(d, out=d)
        worst = float(np.max(d, where=~np.isnan(d), initial=0.0))
    return worst <= rtol * float(np.max(table, where=~np.isnan(table), initial=0.0))


def plausibility(rec: Reconstruction, table: ArrayLike) -> dict[str, Any]:
    """The three checks of the module docstring on ``table`` (3, 90, 90, 180) and ``rec.eval``."""
    t = np.asarray(table)
    t = t if t.dtype in (np.float32, np.float64) else t.astype(np.float64)
    valid = merlgrid.valid_mask()[None]
    # reductions over the valid finite cells in place (no table-sized copies: fresh memory is dear)
    missing = int(np.sum(valid & ~np.isfinite(t)))
    read = valid & ~np.isnan(t)  # what a reader of the table sees (an infinite cell is missing and is read)
    vmin = float(np.min(t, where=read, initial=np.inf)) if read.any() else math.nan
    vmax = float(np.max(t, where=read, initial=0.0))  # 0: the cells below the horizon
    non_neg = {"pass": bool(missing == 0 and vmin >= 0.0), "min_1_per_sr": vmin, "missing_cells": missing,
               "max_1_per_sr": vmax}
    look = lambda wi, wo: np.nan_to_num(merltable.lookup(t, wi, wo, interpolate=True), nan=0.0)  # noqa: E731
    alb, quadrature = checked_albedo(look, 64, 128, mirror=mirror_symmetric(t))
    albedo = {"pass": bool(np.all(alb <= 1.0 + ALBEDO_TOLERANCE)), "max": float(alb.max()),
              "theta_i_deg": ALBEDO_INCIDENCES_DEG.tolist(), "albedo": np.round(alb, 5).tolist(),
              "tolerance": ALBEDO_TOLERANCE, "of": "the written table", "quadrature": quadrature}
    err = reciprocity_error(rec.eval)
    recip = {"pass": bool(err <= RECIPROCITY_TOLERANCE), "relative_error": err,
             "tolerance": RECIPROCITY_TOLERANCE, "of": f"the {rec.method} BRDF; the table is reciprocal by "
                                                       f"construction (phi_d folded)"}
    return {"non_negative": non_neg, "albedo": albedo, "reciprocity": recip,
            "all_pass": bool(non_neg["pass"] and albedo["pass"] and recip["pass"])}
