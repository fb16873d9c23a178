"""The ``fit`` method: analytic lobes fitted to in-plane slices, the number and kind of lobes chosen by BIC.

Model: a sum of lobes from :mod:`reconstruction.core.models` (so the result is a
:class:`~reconstruction.core.models.Material`):
``lambert`` (albedo), ``ggx`` / ``beckmann`` (alpha, specular, optional Schlick Fresnel f0) and ``retro``
(exponent, amount). Geometry parameters (alpha, f0, exponent) are shared by all channels; every lobe has one
amplitude per channel.

Fit (scipy.optimize.least_squares, method "trf"):

* parametrisation: log alpha, logit f0, log exponent, log amplitudes. With Fresnel, the amplitude is the
  normal-incidence reflectance specular * f0 (well determined) and the report gives specular = amplitude / f0;
* residuals (f_model - f) / sigma with sigma = sqrt(std^2 + (relative_sigma f_model)^2 + floor^2): ``std`` from
  the samples, a relative term for calibration and model error (1 % by default) and a floor of 1e-4 of the
  channel's peak that keeps weights finite for noise-free data. The relative term is taken from the model's value
  (a first pass uses the measured value, a warm-started second pass the model's), so an outlying sample does not
  widen its own error bar;
* robust loss ``soft_l1`` with ``f_scale`` = 2 sigma (outliers beyond ~2 sigma weigh linearly, not quadratically);
* start: a grid over the geometry parameters with non-negative linear least squares for the amplitudes
  (variable projection), then the joint non-linear refinement;
* uncertainties: covariance (J^T J)^-1 * max(1, reduced chi^2) from the Jacobian at the solution, carried to the
  reported parameters (alpha, f0, albedo, specular, ...) by the delta method.

Model selection: candidates are fitted stepwise (lambert, ggx, beckmann, lambert + ggx, lambert + beckmann; then the
best of these for each distribution with Fresnel, with a retro lobe, with both, and with a lambert lobe added) and
the one with the lowest BIC = robust chi^2 + k ln(n) is kept, so a lobe stays only when the data require it.

Scene files (``--scene configs/scenes/NAME.toml``, :mod:`reconstruction.core.scene`) say what the reconstruction is
for: the lobe kinds allowed, the angular resolution (lobes narrower than it are not resolved: alpha >=
radians(resolution) / 2.6), the relative_sigma used in the weights and an error budget (relative_rmse: the simplest
candidate within it of the BIC choice over the scene's directions is used). A range the scene file does not give
is taken as 0-85 deg here (:data:`SCENE_DEFAULT_RANGE_DEG`).

The package's rooms: :mod:`.model` (lobe structures, :func:`fit_model`, :class:`FitResult`), :mod:`.selection`
(the BIC search), :mod:`.budget` (what a scene asks), :mod:`.report` (:class:`FitReconstruction` and its report);
:func:`reconstruct_fit` chains them.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np
from numpy.typing import NDArray
from threadpoolctl import threadpool_limits

from reconstruction.base import ReconstructionError
from reconstruction.core.scene import Scene
from reconstruction.core.slicedata import Slice
from reconstruction.methods.fit.budget import (
    SCENE_DEFAULT_RANGE_DEG,
    apply_budget,
    scene_alpha_min,
    scene_directions,
    scene_inside,
)
from reconstruction.methods.fit.model import (
    REFIT_MAX_VALUES,
    SELECTION_MAX_VALUES,
    FitResult,
    LobeSpec,
    _problem,
    f0_of_ior,
    fit_model,
    gap_bounds,
    ior_of_f0,
    model_name,
)
from reconstruction.methods.fit.report import FitReconstruction, fit_info
from reconstruction.methods.fit.resolution import instrument_info
from reconstruction.methods.fit.selection import select_model
from reconstruction.schema.scene import LOBE_KINDS

__all__ = ["LobeSpec", "FitResult", "FitReconstruction", "fit_model", "reconstruct_fit", "scene_alpha_min",
           "scene_directions", "SCENE_DEFAULT_RANGE_DEG", "gap_bounds", "f0_of_ior", "ior_of_f0",
           "model_name"]


def _as_brdf(slices: Slice) -> Slice:
    """``slices`` in f_r (1/sr), checked: 1 or 3 channels and at least 3 samples."""
    if slices.quantity != "brdf":
        f_, std_ = slices.brdf()
        slices = Slice(slices.theta_i_deg, slices.theta_o_deg, f_, list(slices.channels), std_, slices.repeats,
                       slices.unix_time_s, meta={"quantity": "brdf", **({"instrument": slices.meta["instrument"]}
                                                 if slices.meta.get("instrument") is not None else {})},
                       source=slices.source)
    n_c = len(slices.channels)
    if slices.kind == "spectral" or n_c not in (1, 3):
        raise ReconstructionError(f"{slices.source}: fit works on 1 (grey) or 3 (RGB) channels, got {n_c}; "
                                  f"convert spectra with reconstruction.core.colour first")
    if len(slices) < 3:
        raise ReconstructionError(f"{slices.source}: {len(slices)} sample(s); fit needs at least 3")
    return slices


def _allowed(lobes: Sequence[str] | None, scene: Scene | None) -> set[str]:
    allowed = set(lobes if lobes is not None else (scene.lobes if scene and scene.lobes else LOBE_KINDS))
    unknown = allowed - set(LOBE_KINDS)
    if unknown:
        raise ReconstructionError(f"unknown lobe kind(s) {sorted(unknown)}; expected {', '.join(LOBE_KINDS)}")
    if not allowed & {"lambert", "ggx", "beckmann"}:
        raise ReconstructionError("fit needs at least one of the lobes lambert, ggx, beckmann")
    return allowed


@threadpool_limits.wrap(limits=1, user_api="blas")  # tiny matrices: BLAS threads only cost time
def reconstruct_fit(
    slices: Slice,
    *,
    scene: Scene | None = None,
    lobes: Sequence[str] | None = None,
    loss: str = "soft_l1",
    f_scale: float = 2.0,
    relative_sigma: float | None = None,
    progress: Callable[[str], None] | None = None,
    specs: Sequence[LobeSpec] | None = None,
    fit_to_scene: bool = False,
) -> FitReconstruction:
    """Fit analytic lobes to ``slices`` (f_r, 1 or 3 channels) and choose the model by BIC (and the scene).

    ``specs``: fit this model structure only (no search), e.g. to refit a chosen model to a subset of samples.
    ``fit_to_scene`` (with ``specs`` and ``scene``): fit it to the samples inside the scene's ranges, as a
    scene's budget fits the simpler model it chooses (:attr:`FitReconstruction.fitted_to_scene`), so that
    cross-validation refits in every fold the model that was used (all samples when none or every sample is
    inside, or too few for the model's parameters).

    ``lobes``: the lobe kinds allowed (subset of :data:`LOBE_KINDS`; default all, or the scene's list).
    ``relative_sigma``: relative uncertainty added to the samples' std (default the scene's, else 0.01).
    ``progress`` is called with each candidate's name before it is fitted.
    """
    slices = _as_brdf(slices)
    n_c = len(slices.channels)
    allowed = _allowed(lobes, scene)
    rel = relative_sigma if relative_sigma is not None else (scene.relative_sigma if scene and scene.relative_sigma
                                                             else 0.01)
    gaps = gap_bounds(slices)
    # the scene's resolution bounds alpha only when it gives one (the floor is the instrument's, in _problem)
    scene_min = scene_alpha_min(scene) if scene is not None and scene.angular_resolution_deg is not None else 0.0
    full = _problem(slices, rel, max(scene_min, gaps["alpha_min"]))
    full.exponent_max = gaps["retro_exponent_max"]
    # many samples: candidates are compared on an evenly strided subset (every stride-th sample in
    # (theta_i, theta_o) order), then the chosen model is refitted to all samples
    stride = max(1, math.ceil(full.n / SELECTION_MAX_VALUES))
    order = np.lexsort((slices.theta_o_deg, slices.theta_i_deg))
    pick = np.zeros(len(slices), dtype=bool)
    pick[order[::stride]] = True
    prob = full.take(pick) if stride > 1 else full

    fit_mask: NDArray[np.bool_] | None = None  # the samples the chosen model is fitted to, if not all
    if specs is not None and scene is not None and fit_to_scene:
        inside = scene_inside(scene, slices)
        k = sum(len(sp.nonlinear) for sp in specs) + len(specs) * n_c
        if k < int(inside.sum()) * n_c and not inside.all():
            fit_mask = inside
    sel = select_model(prob.take(fit_mask[pick] if stride > 1 else fit_mask) if fit_mask is not None else prob,
                       allowed, n_c, slices.source, len(slices), loss=loss, f_scale=f_scale, progress=progress,
                       specs=specs)
    chosen, why = sel.chosen, sel.reason
    if fit_mask is not None:
        why += f"; fitted to the {int(fit_mask.sum())} samples inside the scene's ranges"
    scene_info: dict[str, Any] | None = None
    bic_specs: tuple[LobeSpec, ...] | None = None
    if scene is not None and specs is None:
        budget = apply_budget(scene, slices, sel.fitted, chosen, why, prob, pick, stride, loss, f_scale)
        if budget.chosen is not chosen:
            bic_specs = chosen.specs
        chosen, why, fit_mask, scene_info = budget.chosen, budget.reason, budget.fit_mask, budget.info

    notes: list[str] = []
    if stride > 1:
        target = full.take(fit_mask) if fit_mask is not None else full
        thin = max(1, math.ceil(target.n / REFIT_MAX_VALUES))
        if thin > 1:  # millions of samples add nothing to a handful of parameters but memory and time
            target = target.take(np.arange(target.f.shape[0]) % thin == 0)
        chosen = fit_model(chosen.specs, target, loss=loss, f_scale=f_scale)
        notes.append(f"candidates compared on 1 in {stride} of the {len(slices)} samples; {chosen.name} refitted "
                     f"to {target.f.shape[0]} samples" + (f" (1 in {thin})" if thin > 1 else ""))
    material = chosen.material(name=f"fit {chosen.name}")
    info = fit_info(slices, full, chosen, material, sel.ranked, why, sel.skipped, fit_mask, gaps, loss, f_scale)
    if scene_info is not None:
        info["scene"] = scene_info
    if full.blur is not None:
        info["instrument"] = instrument_info(full, chosen)
        notes += [n["note"] for n in info["instrument"]["lobes"] if "note" in n]
    if notes:
        info["notes"] = notes
    channels = ["value"] if n_c == 1 else ["R", "G", "B"]
    return FitReconstruction(material, channels, chosen, info, fitted_to_scene=fit_mask is not None,
                             bic_specs=bic_specs)
