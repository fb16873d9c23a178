"""What a fit through a finite instrument can resolve: the chi^2 profile of each microfacet lobe over alpha and the
report's ``instrument`` section (:mod:`reconstruction.methods.fit.aperture` models the cone averages)."""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from reconstruction.methods.fit.aperture import (
    ALPHA_FLOOR,
    NEAR_CONES,
    PROFILE_DELTA_CHI2,
    resolution_alpha,
)
from reconstruction.methods.fit.model import _column, _weighted_nnls

__all__ = ["resolution_notes", "instrument_info"]


def resolution_notes(chosen: Any, prob: Any) -> list[dict[str, Any]]:
    """For each microfacet lobe of the fitted model (with an instrument): the chi^2 profile over alpha (the other
    geometry fixed, amplitudes re-solved), its 2-sigma range, and whether the lobe is below the instrument's
    angular resolution (the range reaches :data:`ALPHA_FLOOR`): then "alpha < X"."""
    blur = prob.blur
    if blur is None:
        return []
    nl, _ = chosen.split()
    amps = chosen.amplitudes()
    cols0 = np.stack([_column(s, p, prob) for s, p in zip(chosen.specs, nl, strict=True)], 1)
    sigma = prob.sigma_of(cols0 @ amps)
    notes = []
    grid = np.geomspace(ALPHA_FLOOR, 1.0, 41)
    for li, spec in enumerate(chosen.specs):
        if spec.kind not in ("ggx", "beckmann"):
            continue
        chi = np.empty(grid.size)
        for k, a in enumerate(grid):  # 41 NNLS solves of a few columns
            p = nl[li].copy()
            p[0] = math.log(a)
            cols = cols0.copy()
            cols[:, li] = _column(spec, p, prob)
            chi[k] = _weighted_nnls(cols, prob.f, sigma)[1]
        alpha = float(math.exp(nl[li][0]))
        best = int(np.argmin(chi))
        ok = chi <= chi[best] + PROFILE_DELTA_CHI2
        lo, hi = best, best
        while lo > 0 and ok[lo - 1]:
            lo -= 1
        while hi < grid.size - 1 and ok[hi + 1]:
            hi += 1
        upper = float(grid[min(hi + 1, grid.size - 1)])  # the first alpha the data rule out
        half_deg = blur.instrument.aperture_half_angle_deg
        a_res = resolution_alpha(half_deg)
        # unresolved: the data cannot tell the lobe from a narrower one, or even the widest alpha they allow
        # is narrower than the instrument resolves (its shape is the cone's; alpha shows only in the tails)
        unresolved = lo == 0 or upper < a_res
        note: dict[str, Any] = {"lobe": li, "alpha": alpha, "alpha_range_2sigma": [float(grid[lo]), upper],
                                "resolution_alpha": round(a_res, 6), "resolved": not unresolved}
        if unresolved:
            bound = max(upper, a_res)
            note["alpha_upper_bound"] = bound
            note["note"] = (f"below the instrument's angular resolution, alpha < {bound:.3g} (a {half_deg:.3g} deg "
                            f"cone; the lobe's energy is kept: specular = "
                            f"{', '.join(f'{v:.4g}' for v in amps[li])})")
        notes.append(note)
    return notes


def instrument_info(prob: Any, chosen: Any) -> dict[str, Any]:
    """The report's ``instrument`` section: the instrument, where the cone averages were used, the lobes' notes."""
    blur = prob.blur
    return {"instrument": blur.instrument.to_meta(),
            "aperture_half_angle_deg": round(blur.instrument.aperture_half_angle_deg, 6),
            "model": "microfacet lobes averaged over the detector cone (and the source's divergence) at the samples "
                     f"within {NEAR_CONES:g} cone half angles (or 3 deg) of their mirror direction; point values "
                     "elsewhere",
            "cone_averaged_samples": int(blur.pos.size),
            "lobes": resolution_notes(chosen, prob)}
