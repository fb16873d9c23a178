"""The fit's scene budget: what a scene file asks of the fit (the smallest alpha worth resolving, the directions
it is judged over) and the choice of the simplest candidate within the scene's error budget."""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.core.geometry import sph_to_vec
from reconstruction.core.metrics import relative_rmse_cos_dirs
from reconstruction.core.scene import RECONSTRUCTION_DEFAULT_RANGE_DEG, Scene
from reconstruction.core.slicedata import Slice
from reconstruction.methods.fit.model import ALPHA_MIN, Array, FitResult, _Problem, fit_model

__all__ = ["SCENE_DEFAULT_RANGE_DEG", "scene_alpha_min", "scene_directions", "scene_inside", "Budget", "apply_budget"]

#: theta_i and theta_o range (degrees) of a scene whose file gives none, for the fit (the capture's default differs:
#: :data:`reconstruction.core.scene.CAPTURE_DEFAULT_RANGE_DEG`).
SCENE_DEFAULT_RANGE_DEG = RECONSTRUCTION_DEFAULT_RANGE_DEG


def scene_alpha_min(scene: Scene | None) -> float:
    """Smallest microfacet alpha worth resolving in ``scene`` (dimensionless)."""
    if scene is None or scene.angular_resolution_deg is None:
        return ALPHA_MIN
    return max(ALPHA_MIN, math.radians(scene.angular_resolution_deg) / 2.6)


def scene_directions(scene: Scene, max_pairs: int = 200_000) -> tuple[Array, Array]:
    """Direction pairs (M, 3) spanning ``scene``: theta_i, theta_o in its ranges, relative azimuth 0-180 deg."""
    (ti_lo, ti_hi), (to_lo, to_hi) = scene.ranges(SCENE_DEFAULT_RANGE_DEG)
    step = max(1.0, scene.angular_resolution_deg or 2.0)
    while True:
        ti = np.radians(np.arange(ti_lo, ti_hi + 1e-9, step))
        to = np.radians(np.arange(to_lo, to_hi + 1e-9, step))
        ph = np.radians(np.arange(0.0, 180.0 + 1e-9, step))
        if ti.size * to.size * ph.size <= max_pairs:
            break
        step *= 1.5
    a, b, p = np.meshgrid(ti, to, ph, indexing="ij")
    wi = sph_to_vec(a.ravel(), np.pi)
    wo = sph_to_vec(b.ravel(), np.pi + p.ravel())
    return wi, wo


def scene_inside(scene: Scene, slices: Slice) -> NDArray[np.bool_]:
    """(N,) True for the samples of ``slices`` inside the scene's theta_i and |theta_o| ranges (what the scene
    needs; a range the file does not give is :data:`SCENE_DEFAULT_RANGE_DEG`)."""
    (ti_lo, ti_hi), (to_lo, to_hi) = scene.ranges(SCENE_DEFAULT_RANGE_DEG)
    ti, to = slices.theta_i_deg, np.abs(slices.theta_o_deg)
    return (ti >= ti_lo - 1e-9) & (ti <= ti_hi + 1e-9) & (to >= to_lo - 1e-9) & (to <= to_hi + 1e-9)


def _scene_report(scene: Scene) -> dict[str, Any]:
    ti, to = scene.ranges(SCENE_DEFAULT_RANGE_DEG)
    return {"name": scene.name, "source": scene.source, "theta_i_deg": list(ti), "theta_o_deg": list(to),
            "angular_resolution_deg": scene.angular_resolution_deg,
            "lobes": list(scene.lobes) if scene.lobes else None, "relative_rmse": scene.relative_rmse,
            "relative_sigma": scene.relative_sigma}


@dataclass
class Budget:
    """What the scene made of the BIC choice: the model used, why, the samples it is to be fitted to (None: all)
    and the report's ``scene`` section."""

    chosen: FitResult
    reason: str
    fit_mask: NDArray[np.bool_] | None
    info: dict[str, Any]


def apply_budget(scene: Scene, slices: Slice, fitted: dict[str, FitResult], chosen: FitResult, reason: str,
                 prob: _Problem, pick: NDArray[np.bool_], stride: int, loss: str, f_scale: float) -> Budget:
    """Simpler candidates, refitted to the samples inside the scene's ranges (the rest does not matter to the
    scene), are compared with the BIC choice ``chosen`` over the scene's directions; the simplest within the
    budget (``relative_rmse``) is used. ``prob`` holds the samples ``pick`` of ``slices`` (1 in ``stride``)."""
    info: dict[str, Any] = {"scene": _scene_report(scene)}
    fit_mask: NDArray[np.bool_] | None = None
    (ti_lo, ti_hi), _ = scene.ranges(SCENE_DEFAULT_RANGE_DEG)
    if scene.relative_rmse is not None:
        inside = scene_inside(scene, slices)
        in_prob = inside[pick] if stride > 1 else inside
        sub = prob.take(in_prob) if 0 < in_prob.sum() < prob.f.shape[0] else prob
        swi, swo = scene_directions(scene)
        ref = chosen.material().eval(swi, swo)
        diffs = []
        for k in sorted({r.k for r in fitted.values() if r.k < min(chosen.k, sub.n)}):  # simplest first
            best: tuple[float, FitResult] | None = None
            for r in (r for r in fitted.values() if r.k == k):
                rr = fit_model(r.specs, sub, loss=loss, f_scale=f_scale) if sub is not prob else r
                e = relative_rmse_cos_dirs(rr.material().eval(swi, swo), ref, swi, swo)
                diffs.append({"model": r.name, "k": k, "relative_rmse_vs_bic_choice": round(e, 5)})
                if e <= scene.relative_rmse and (best is None or e < best[0]):
                    best = (e, rr)
            if best is not None:
                reason = (f"simplest candidate within the scene's error budget: {best[1].name}, fitted to the "
                          f"{sub.f.shape[0]} samples inside the scene's ranges, differs from the BIC choice "
                          f"{chosen.name} by {best[0]:.4f} relative RMSE of f cos cos over the scene's directions "
                          f"(budget {scene.relative_rmse})")
                chosen = best[1]
                if sub is not prob:
                    fit_mask = inside
                break
        info["budget_comparison"] = diffs
        info["samples_inside_scene"] = int(sub.f.shape[0])
    lo_i, hi_i = float(np.min(slices.theta_i_deg)), float(np.max(slices.theta_i_deg))
    if ti_hi > hi_i + 1e-9 or ti_lo < lo_i - 1e-9:
        info["warning"] = (f"the scene uses theta_i {ti_lo:g}-{ti_hi:g} deg "
                           f"but the data cover {lo_i:g}-{hi_i:g} deg; outside that the fit extrapolates")
    return Budget(chosen, reason, fit_mask, info)
