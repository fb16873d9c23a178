"""Method dispatch: ``fit``, ``bivariate``, ``revolve`` and ``auto``, and tabulation of the result.

``auto`` chooses from the data at hand:

1. ``fit`` is tried first (it is fast). If the chosen analytic model explains the samples, i.e. the relative RMSE
   of f cos(theta_i) cos(theta_o) at the samples is <= 3 %, or the samples carry standard deviations and the
   reduced chi^2 is <= 3, ``fit`` is used: an analytic model extrapolates to the unmeasured table physically.
2. Otherwise, with slices at 3 or more incidences, ``bivariate``: the lines cover the (theta_h, theta_d) plane
   well enough to interpolate the data themselves.
3. Otherwise (one or two incidences), ``revolve``, the thesis's solids of revolution, made for a single slice.

The choice and its reason (with the figures) go into the report.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import merl
from .base import Reconstruction, ReconstructionError
from .bivariate import reconstruct_bivariate
from .fit import FitReconstruction, reconstruct_fit
from .inputs import check_slice
from .metrics import directional_albedo
from .report import ALBEDO_INCIDENCES_DEG, ALBEDO_TOLERANCE
from .revolve import reconstruct_revolve
from .scene import Scene
from .slicefile import Slice

Array = NDArray[np.float64]

__all__ = ["METHODS", "AUTO_FIT_TOLERANCE", "AUTO_FIT_CHI2", "Options", "reconstruct", "tabulate"]

METHODS = ("auto", "fit", "revolve", "bivariate")
AUTO_FIT_TOLERANCE = 0.03
AUTO_FIT_CHI2 = 3.0
AUTO_MIN_INCIDENCES = 3


@dataclass
class Options:
    """Method options. ``fill``: "interpolate" holes (default) or leave them "zero" (bivariate, revolve)."""

    scene: Scene | None = None
    fill: str = "interpolate"
    lobes: Sequence[str] | None = None
    revolve_axis: str = "auto"
    revolve_smoothing: float | None = None
    cos_power: float | None = None  # bivariate: None = its default for the number of incidences


def _run(method: str, s: Slice, opts: Options, progress: Callable[[str], None] | None) -> Reconstruction:
    if method == "fit":
        return reconstruct_fit(s, scene=opts.scene, lobes=opts.lobes, progress=progress)
    if method == "bivariate":
        return reconstruct_bivariate(s, fill=opts.fill, cos_power=opts.cos_power)
    if method == "revolve":
        # reciprocal: f(wi, wo) and f(wo, wi) averaged, so the BRDF passes the reciprocity check (same accuracy,
        # a full table still well under 1 s)
        kw: dict[str, Any] = {"axis": opts.revolve_axis, "fill": opts.fill, "reciprocal": True}
        if opts.revolve_smoothing is not None:
            kw["smoothing"] = opts.revolve_smoothing
        return reconstruct_revolve(s, **kw)
    raise ReconstructionError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")


def _fit_explains(rec: FitReconstruction, s: Slice) -> tuple[bool, str]:
    # a model that reflects more light than it receives somewhere is not used, however well it fits the
    # samples (with few photons a fit can extrapolate wildly outside the measured plane)
    alb = directional_albedo(rec.eval, np.radians(ALBEDO_INCIDENCES_DEG), 64, 128)
    if alb.max() > 1.0 + ALBEDO_TOLERANCE:
        k = int(np.argmax(alb.max(axis=1)))
        return False, (f"the best analytic model, {rec.result.name}, is not physically plausible: its directional "
                       f"albedo reaches {alb.max():.3g} > 1 at theta_i = {ALBEDO_INCIDENCES_DEG[k]:g} deg")
    res = rec.info["residuals"]
    rel, chi2r = float(res["relative_rmse_cos"]), float(res["chi2_reduced"])
    has_std = s.std is not None and bool(np.any(s.std > 0))
    if rel <= AUTO_FIT_TOLERANCE:
        return True, (f"the analytic model {rec.result.name} reproduces the samples to {rel:.2%} relative RMSE of "
                      f"f cos cos (<= {AUTO_FIT_TOLERANCE:.0%}), so it is used to extrapolate the whole table")
    if has_std and chi2r <= AUTO_FIT_CHI2:
        return True, (f"the analytic model {rec.result.name} agrees with the samples within their standard "
                      f"deviations (reduced chi^2 {chi2r:.2f} <= {AUTO_FIT_CHI2:g})")
    return False, (f"the best analytic model, {rec.result.name}, misses the samples by {rel:.2%} relative RMSE "
                   f"(> {AUTO_FIT_TOLERANCE:.0%})" + (f" and reduced chi^2 {chi2r:.1f}" if has_std else ""))


def reconstruct(s: Slice, method: str = "auto", opts: Options | None = None,
                progress: Callable[[str], None] | None = None) -> tuple[Reconstruction, dict[str, Any]]:
    """Reconstruct ``s`` (f_r, grey or RGB) with ``method``; returns (reconstruction, choice) where choice holds
    ``requested``, ``used`` and ``reason``."""
    opts = opts or Options()
    check_slice(s)  # too few samples, NaN/inf, all zero, duplicates: a clear error before any method runs
    s = s.sorted()  # by (theta_i, theta_o): the order the methods expect (captures may be in any order)
    if method not in METHODS:
        raise ReconstructionError(f"unknown method {method!r}; expected one of {', '.join(METHODS)}")
    if method != "auto":
        rec = _run(method, s, opts, progress)
        return rec, {"requested": method, "used": rec.method, "reason": f"requested with --method {method}"}
    n_inc = int(np.unique(s.theta_i_deg).size)
    fit_rec = reconstruct_fit(s, scene=opts.scene, lobes=opts.lobes, progress=progress)
    ok, why_fit = _fit_explains(fit_rec, s)
    if ok:
        return fit_rec, {"requested": "auto", "used": "fit", "reason": why_fit}
    if n_inc >= AUTO_MIN_INCIDENCES:
        rec = _run("bivariate", s, opts, progress)
        return rec, {"requested": "auto", "used": "bivariate",
                     "reason": f"{why_fit}; slices at {n_inc} incidences cover the (theta_h, theta_d) plane, so "
                               f"the data are interpolated between the measured lines"}
    rec = _run("revolve", s, opts, progress)
    return rec, {"requested": "auto", "used": rec.method,
                 "reason": f"{why_fit}; with {n_inc} incidence(s) the solids-of-revolution method, made for a "
                           f"single slice, is used"}


def tabulate(rec: Reconstruction, supersample: tuple[int, int, int] | str | None = None) -> Array:
    """The MERL table (3, 90, 90, 180) of ``rec``: bin-centre values, or cell averages with ``supersample``
    ((nh, nd, np) or "adaptive", see :func:`reconstruction.merl.tabulate`).

    Uses the method's own fast ``table()`` for bin centres when it has one; otherwise ``merl.tabulate``.
    Raises :class:`ReconstructionError` if a cell above the horizon is not finite or is negative.
    """
    fast = getattr(rec, "table", None)
    t = fast() if (supersample is None and callable(fast)) else merl.tabulate(rec.eval, supersample=supersample)
    valid = merl.valid_mask()[None]
    bad = valid & ~np.isfinite(t)
    if bad.any():
        raise ReconstructionError(f"method {rec.method}: {int(bad.sum())} table cell(s) above the horizon have no "
                                  f"finite value")
    neg = valid & (t < 0)
    if neg.any():
        raise ReconstructionError(f"method {rec.method}: {int(neg.sum())} table cell(s) are negative (min "
                                  f"{float(t[neg].min()):.3g})")
    return t
