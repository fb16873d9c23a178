"""Cross-validated prediction error of reconstruction methods on the measured samples (what ``auto`` chooses by).

A method's residual on its own samples says nothing about the table (``bivariate`` interpolates its samples
exactly and can still be far off elsewhere), so methods are compared on samples they did not see:

* slices at several incidences: **leave-one-incidence-out**, each incidence predicted from the others (with more
  than ``n_blocks`` incidences, ``n_blocks`` groups of neighbouring incidences, each predicted from the rest);
* points anywhere on the hemisphere (a Zemax or RGL file: :class:`~reconstruction.core.samples.PointFolds`, which
  ``auto`` cross-validates on instead of the in-plane rows): the same folds over whole incidences, every point of
  an incidence held out together and predicted from the points of the others;
* one incidence: **held-out contiguous blocks of theta_o**: the whole forward side beyond the specular peak as
  one block (it lies on theta_d = theta_i + theta_h, so predicting it from the rest tests the extrapolation in
  theta_d that the table needs at every other incidence) and the backward side in ``n_blocks`` - 1 blocks of
  neighbouring outgoing angles (so interpolation between immediate neighbours cannot hide a bad model). The
  samples within two steps of the mirror direction are never held out: every table is built on its measured
  specular peak, and a peak predicted from its shoulders alone would rank the methods by a guess the table never
  has to make.

Two errors are pooled over every held-out sample and channel. The **image error** ranks the methods
(:attr:`CVScore.criterion`): each sample is what a renderer shows of the material, the pixel of a sphere lit by a
point light from its incidence and seen from its outgoing direction (radiance f cos(theta_i)), tone-mapped as the
image metric tone-maps a render (exposed at the :data:`IMAGE_EXPOSURE_QUANTILE` quantile of every sample's radiance,
clipped, gamma :data:`IMAGE_GAMMA`), and the error is the RMS difference of those pixel values: the dim
off-specular level that covers most of a rendered sphere counts as a renderer counts it, where the linear error,
dominated by the specular peak's values, ignores it (on the real materials of benchmarks/bench_real_materials.py
a method that wrote a diffuse level 30 times the measured one off the peak of a glossy paint won on the linear
error). The **relative RMSE** of f cos(theta_i) cos(theta_o) (the table metric's weighting) is reported beside it
and is what a scene's error budget and the samples' noise level are compared with.

``fit`` is cross-validated with its model structure fixed to the one chosen on all samples (its lobes refitted in
every fold to the samples it was fitted to: those inside a scene's ranges when the scene's budget chose a simpler
model), so the score is of that model. With a scene, only the held-out
samples inside its ranges count (:func:`scene_mask`), and :func:`budget_check` compares the choice's error with
the scene's error budget.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.base import Reconstruction, ReconstructionError
from reconstruction.core.metrics import tone_map
from reconstruction.core.samples import DirectionalSlice, out_of_plane, sample_directions
from reconstruction.core.slicedata import Slice

Array = NDArray[np.float64]

__all__ = ["folds", "sweep_folds", "cross_validate", "score_predictions", "CVScore", "N_BLOCKS", "budget_check",
           "SceneBudgetWarning", "IMAGE_EXPOSURE_QUANTILE", "image_values"]

N_BLOCKS = 8
#: The held-out image error's exposure: this quantile of the samples' radiance f cos(theta_i) (pooled over channels)
#: maps to white. Chosen by replaying auto's choice on every method's held-out predictions and rendered images for
#: 115 of the real materials, 1-3 slices (docs/real-materials.md): 0.8-0.9 ranked best; lower quantiles clip the
#: glossy shoulders, higher ones darken the rest.
IMAGE_EXPOSURE_QUANTILE = 0.9


def folds(s: Slice, n_blocks: int = N_BLOCKS) -> tuple[str, list[NDArray[np.bool_]]]:
    """(scheme, held-out masks (N,) bool) for ``s``."""
    inc = np.unique(s.theta_i_deg)
    if 2 <= inc.size <= n_blocks:
        return "leave-one-incidence-out", [s.theta_i_deg == t for t in inc]
    if inc.size > n_blocks:
        groups = np.array_split(inc, n_blocks)
        return (f"leave-one-group-out ({n_blocks} groups of neighbouring incidences)",
                [np.isin(s.theta_i_deg, g) for g in groups])
    to = s.theta_o_deg
    step = float(np.median(np.diff(np.unique(to)))) if np.unique(to).size > 1 else 1.0
    keep = np.abs(to - inc[0]) <= 2.0 * step + 1e-9  # the specular peak stays in every training set
    forward = ~keep & (to > inc[0])
    masks = [forward] if forward.sum() >= 2 else []
    back = ~keep & ~(forward if masks else np.zeros_like(keep))
    order = np.argsort(np.where(back, to, np.inf), kind="stable")[: int(np.sum(back))]
    k = max(1, min(n_blocks - len(masks), order.size // 3))
    for block in np.array_split(order, k):  # contiguous runs of theta_o
        m = np.zeros(len(s), dtype=bool)
        m[block] = True
        masks.append(m)
    fwd = "the forward side beyond the peak and " if forward.sum() >= 2 else ""
    return (f"{len(masks)} held-out contiguous blocks of theta_o ({fwd}{k} on the other side; the mirror direction "
            f"+- {2 * step:g} deg always kept)"), masks


def sweep_folds(p: DirectionalSlice) -> tuple[str, list[NDArray[np.bool_]]]:
    """(scheme, held-out masks) for a bench's sweeps in the plane of incidence and out of it (a tilted sample; not
    a scanned hemisphere): the in-plane samples' folds as :func:`folds` makes them without the others (each trained
    on every other sample, the sweeps out of the plane included), then each sweep out of the plane (one light
    direction) held out whole. A capture and its superset so share the subset's folds, and a method is judged on
    the new sweeps beside them (every method predicts them: in-plane methods from the in-plane rows)."""
    inplane = ~out_of_plane(p)
    masks: list[NDArray[np.bool_]] = []
    scheme = "no in-plane samples"
    where = np.nonzero(inplane)[0]
    if where.size:
        scheme, sub = folds(Slice.take(p, where))  # the in-plane angles of the points (as a slice gives them)
        for m in sub:  # a handful
            full = np.zeros(len(p), dtype=bool)
            full[where[m]] = True
            masks.append(full)
    out = np.nonzero(~inplane)[0]
    _, group = np.unique(np.round(p.wi[out], 6), axis=0, return_inverse=True)
    group = group.reshape(-1)
    n_out = int(group.max()) + 1 if out.size else 0
    for k in range(n_out):  # one per sweep out of the plane
        m = np.zeros(len(p), dtype=bool)
        m[out[group == k]] = True
        masks.append(m)
    return f"{scheme}; and each of the {n_out} sweep(s) out of the plane of incidence held out whole", masks


@dataclass
class CVScore:
    """Held-out error of one method."""

    method: str
    error: float  # relative RMSE of f cos cos over all held-out samples; inf if a fold failed
    fold_errors: list[float]
    seconds: float
    failure: str | None = None
    predictions: Array | None = None  # (N, C) each sample predicted by the fold that held it out (NaN: never)
    anchor: float | None = None  # prior: the weight of the bivariate interpolation (None: not a prior variant)
    variant: str | None = None  # another variant of the method (e.g. fit's BIC choice beside a scene's budget's)
    image_error: float = math.nan  # RMS difference of the held-out samples tone-mapped as pixels (module doc)

    @property
    def criterion(self) -> float:
        """What auto ranks by: the image error, or the relative RMSE where there is none (a score built by hand)."""
        return self.image_error if not math.isnan(self.image_error) else self.error

    @property
    def label(self) -> str:
        """The method, with its anchor for a prior variant ("prior (anchor 0.25)") or its variant."""
        if self.anchor:
            return f"{self.method} (anchor {self.anchor:g})"
        return f"{self.method} ({self.variant})" if self.variant else self.method

    def as_dict(self) -> dict[str, Any]:
        return {"method": self.method, "label": self.label,
                "held_out_relative_rmse_cos": self.error if math.isfinite(self.error) else None,
                "held_out_image_error": self.image_error if math.isfinite(self.image_error) else None,
                "fold_errors": [e if math.isfinite(e) else None for e in self.fold_errors],
                "seconds": round(self.seconds, 3), **({"failure": self.failure} if self.failure else {}),
                **({"prior_anchor": self.anchor} if self.anchor is not None else {}),
                **({"variant": self.variant} if self.variant else {})}


def _score(pred: Array, f: Array, c: Array) -> tuple[float, float]:
    return float(np.sum(((pred - f) * c) ** 2)), float(np.sum((f * c) ** 2))


def image_values(f: ArrayLike, cos_i: ArrayLike, exposure: float) -> Array:
    """Samples f (N, C) as a renderer's tone-mapped pixels: the radiance f cos(theta_i) (``cos_i`` (N, 1)) of a unit
    point light, the radiance ``exposure`` mapped to white, as the image metric tone-maps a render
    (:func:`reconstruction.core.metrics.tone_map`: clipped to [0, 1], to the power 1 / :data:`IMAGE_GAMMA`).

    >>> image_values(np.array([[0.0], [0.5], [4.0]]), np.ones((3, 1)), 2.0).round(3).ravel().tolist()
    [0.0, 0.533, 1.0]
    """
    radiance = np.maximum(np.asarray(f, dtype=np.float64), 0.0) * np.asarray(cos_i, dtype=np.float64)
    return tone_map(radiance, 1.0 / exposure)


def _exposure(f: Array, cos_i: Array) -> float:
    """The held-out image error's exposure: :data:`IMAGE_EXPOSURE_QUANTILE` of every sample's radiance."""
    r = np.maximum(f, 0.0) * cos_i
    r = r[np.isfinite(r)]
    return float(np.quantile(r, IMAGE_EXPOSURE_QUANTILE)) if r.size else 0.0


def noise_level(s: Slice, score_mask: NDArray[np.bool_] | None = None) -> float:
    """The held-out error a perfect model would have: the relative RMSE of f cos cos that the samples' own standard
    deviations (of the mean) amount to, pooled as :func:`cross_validate` pools its error (0 without std)."""
    f, sd = s.brdf()
    wi, wo = sample_directions(s)
    if score_mask is not None:
        f, sd, wi, wo = f[score_mask], sd[score_mask], wi[score_mask], wo[score_mask]
    c = (np.clip(wi[:, 2], 0, None) * np.clip(wo[:, 2], 0, None))[:, None]
    den = float(np.sum((f * c) ** 2))
    return math.sqrt(float(np.sum((np.nan_to_num(sd) * c) ** 2)) / den) if den > 0 else 0.0


def scene_mask(s: Slice, scene: Any) -> NDArray[np.bool_] | None:
    """The samples inside a scene's theta_i and |theta_o| ranges (what the scene needs), or None for no scene."""
    if scene is None:
        return None
    from reconstruction.methods.fit.budget import scene_inside

    return scene_inside(scene, s)


def cross_validate(s: Slice, name: str, build: Callable[[Slice], Reconstruction],
                   masks: list[NDArray[np.bool_]], score_mask: NDArray[np.bool_] | None = None) -> CVScore:
    """Held-out error of ``build`` (a function of the training slice) over the folds ``masks``; with
    ``score_mask`` only the held-out samples inside it count (a scene's directions)."""
    f, _ = s.brdf()
    wi, wo = sample_directions(s)  # in-plane, or anywhere for points (reconstruction.core.samples.PointFolds)
    t0 = time.perf_counter()
    held_pred = np.full(f.shape, np.nan)
    for k, held in enumerate(masks):  # a handful of folds
        out = held & score_mask if score_mask is not None else held
        if not out.any():
            continue
        train = s.take(~held)
        try:
            rec = build(train)
            pred = np.asarray(rec.eval(wi[out], wo[out]), dtype=np.float64).reshape(int(out.sum()), -1)
        except (ReconstructionError, ValueError, np.linalg.LinAlgError) as e:
            return CVScore(name, math.inf, [], time.perf_counter() - t0, f"fold {k + 1}: {e}")
        if not np.all(np.isfinite(pred)):
            return CVScore(name, math.inf, [], time.perf_counter() - t0, f"fold {k + 1}: non-finite values")
        held_pred[out] = np.broadcast_to(pred, f[out].shape)
    return score_predictions(s, name, held_pred, masks, score_mask, time.perf_counter() - t0)


def score_predictions(s: Slice, name: str, pred: Array, masks: list[NDArray[np.bool_]],
                      score_mask: NDArray[np.bool_] | None = None, seconds: float = 0.0) -> CVScore:
    """The :class:`CVScore` of held-out predictions ``pred`` (N, C) made by the folds ``masks`` (NaN where a
    sample was never held out): pooled and per fold as :func:`cross_validate` scores them. Scores a combination
    of methods (e.g. a blend of two methods' held-out predictions) without fitting again."""
    f, _ = s.brdf()
    wi, wo = sample_directions(s)  # in-plane, or anywhere for points (reconstruction.core.samples.PointFolds)
    ci = np.clip(wi[:, 2], 0, None)[:, None]
    c = ci * np.clip(wo[:, 2], 0, None)[:, None]
    pred = np.broadcast_to(np.asarray(pred, dtype=np.float64), f.shape)
    exposure = _exposure(f, ci)
    num = den = sq = 0.0
    n = 0
    per: list[float] = []
    for held in masks:  # a handful of folds
        out = held & score_mask if score_mask is not None else held
        if not out.any():
            continue
        if not np.all(np.isfinite(pred[out])):
            return CVScore(name, math.inf, per, seconds, f"fold {len(per) + 1}: no finite prediction")
        a, b = _score(pred[out], f[out], c[out])
        num += a
        den += b
        per.append(math.sqrt(a / b) if b > 0 else math.inf)
        if exposure > 0:
            d = image_values(pred[out], ci[out], exposure) - image_values(f[out], ci[out], exposure)
            sq += float(np.sum(d * d))
            n += d.size
    why = None
    if not per and score_mask is not None and any(h.any() for h in masks):
        why = "no held-out sample lies inside the scene's directions to judge it by"
    elif not per:  # nothing was held out: say why, so that a refusal names each method's real reason
        why = ("no sample could be held out to judge it (every sample is kept for training: too few samples away "
               "from the mirror direction, or one block of theta_o)")
    elif den <= 0:
        why = "the held-out samples carry no signal to judge it by (f_r cos cos is zero on all of them)"
    return CVScore(name, math.sqrt(num / den) if den > 0 else math.inf, per, seconds, why,
                   predictions=np.array(pred), image_error=math.sqrt(sq / n) if n else math.nan)


class SceneBudgetWarning(UserWarning):
    """``auto`` chose a method whose held-out error over a scene's samples exceeds the scene's error budget."""


def budget_check(scene: Any, best: CVScore, scores: list[CVScore], noise: float = 0.0) -> dict[str, Any]:
    """The ``cross_validation`` keys ``error_budget`` and ``over_budget`` (and ``over_budget_warning``, what the
    console shows) of the choice ``best`` against the ``scene``'s ``relative_rmse`` ({} without a budget): its
    held-out error over the scene's samples is what the budget bounds. ``noise``: the error the samples' own
    noise amounts to (:func:`noise_level`), said when it is a good part of the excess."""
    if scene is None or scene.relative_rmse is None:
        return {}
    budget = float(scene.relative_rmse)
    if best.error <= budget:
        return {"error_budget": budget, "over_budget": False}
    lowest = min(scores, key=lambda c: c.error)
    msg = (f"the choice, {best.label}, predicts the held-out samples inside scene {scene.name!r} to "
           f"{best.error:.2%} relative RMSE of f cos cos, over the scene's error budget of {budget:.2%}"
           + ("" if lowest is best else f" (the lowest of any method: {lowest.label} {lowest.error:.2%})")
           + (f"; the samples' own noise amounts to {noise:.2%}" if noise > 0.5 * budget else "")
           + "; measure more incidences inside the scene's ranges"
           + (" or with less noise" if noise > 0.5 * budget else "") + ", or loosen the budget")
    return {"error_budget": budget, "over_budget": True, "over_budget_warning": msg}
