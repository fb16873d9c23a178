"""Method dispatch (through :mod:`reconstruction.methods`), ``auto``, and tabulation of the result.

``auto`` chooses by prediction, never by a method's residual on its own samples:

1. ``fit`` is run on all samples (its model is chosen by BIC, honouring ``--scene``);
2. every registered method (``fit`` with that model structure, ``microfacet``, ``revolve``, ``bivariate``) is
   cross-validated on the measured samples (:mod:`reconstruction.crossval`: leave-one-incidence-out with several
   incidences, held-out contiguous blocks of theta_o with one);
3. the method with the lowest held-out relative RMSE of f cos cos whose BRDF is physically plausible (directional
   albedo <= 1 + tolerance at every incidence) is used. With a single incidence, held-out samples of the same
   slice cannot show how a method extrapolates to other incidences (its Fresnel rise or shadowing towards
   grazing theta_d), so ``bivariate``, which holds the peak's microfacet content instead of extrapolating a
   model, is preferred unless another method predicts the held-out samples at least twice as well
   (:data:`SINGLE_SLICE_MARGIN`; on the 48 real MERL materials this lowers auto's median table error from one
   slice from 48 % to 41 %, see docs/real-materials.md, and an exact model, such as a simulated lambert + ggx
   material, still wins by far more).

The report's ``cross_validation`` section holds the scheme, every method's held-out error and the choice.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np
from numpy.typing import NDArray

from . import merl
from .base import Reconstruction, ReconstructionError
from .crossval import CVScore, cross_validate, folds, scene_mask
from .inputs import check_slice
from .methods import REGISTRY, Options, get
from .metrics import directional_albedo
from .report import ALBEDO_INCIDENCES_DEG, ALBEDO_TOLERANCE
from .slicefile import Slice

Array = NDArray[np.float64]

__all__ = ["METHODS", "Options", "reconstruct", "tabulate", "max_albedo"]

METHODS = ("auto", *REGISTRY)
CV_MAX_SAMPLES = 3000
CV_MAX_INCIDENCES = 24
SINGLE_SLICE_PREFERRED = "bivariate"
SINGLE_SLICE_MARGIN = 2.0


def max_albedo(rec: Reconstruction) -> tuple[float, float]:
    """(largest directional albedo over channels and theta_i = 0-85 deg, the theta_i in degrees where it is)."""
    alb = directional_albedo(rec.eval, np.radians(ALBEDO_INCIDENCES_DEG), 48, 96)
    k = int(np.argmax(alb.max(axis=1)))
    return float(alb.max()), float(ALBEDO_INCIDENCES_DEG[k])


def thin_for_cv(s: Slice, max_samples: int = CV_MAX_SAMPLES, max_incidences: int = CV_MAX_INCIDENCES) -> Slice:
    """A subsample of a large ``s`` (sorted) to cross-validate on: at most ``max_incidences`` evenly spread
    incidences and, within each, every k-th outgoing angle so about ``max_samples`` remain (the samples nearest
    the mirror direction always kept). ``s`` itself when it is small enough."""
    inc = np.unique(s.theta_i_deg)
    if len(s) <= max_samples and inc.size <= max_incidences:
        return s
    keep_inc = inc[np.unique(np.round(np.linspace(0, inc.size - 1, min(inc.size, max_incidences))).astype(int))]
    per = max(8, max_samples // keep_inc.size)
    keep = np.zeros(len(s), dtype=bool)
    for t in keep_inc:  # at most max_incidences
        idx = np.nonzero(s.theta_i_deg == t)[0]
        step = max(1, int(np.ceil(idx.size / per)))
        keep[idx[::step]] = True
        keep[idx[np.argsort(np.abs(s.theta_o_deg[idx] - t))[:3]]] = True  # the specular peak
    return s.take(keep)


def _auto(s: Slice, opts: Options, progress: Callable[[str], None] | None) -> tuple[Reconstruction, dict[str, Any]]:
    from .fit import FitReconstruction, reconstruct_fit

    fit_rec = get("fit").build(s, opts, progress)
    assert isinstance(fit_rec, FitReconstruction)
    specs = fit_rec.result.specs
    full = s
    s = thin_for_cv(full)  # cross-validation of a large input on a subsample; the chosen method uses every sample
    scheme, masks = folds(s)
    builders: dict[str, Callable[[Slice], Reconstruction]] = {}
    for name, m in REGISTRY.items():
        if name == "fit":
            builders[name] = lambda tr: reconstruct_fit(tr, scene=opts.scene, lobes=opts.lobes, specs=specs)
        else:
            builders[name] = lambda tr, m=m: m.build(tr, opts, None)
    inside = scene_mask(s, opts.scene)
    if inside is not None and not inside.any():
        inside = None  # no sample inside the scene: judge on all of them
    scores: list[CVScore] = []
    for name, build in builders.items():  # a handful of methods
        if progress:
            progress(f"cross-validating {name}")
        scores.append(cross_validate(s, name, build, masks, inside))
    single = np.unique(s.theta_i_deg).size == 1
    handicap = {m: (SINGLE_SLICE_MARGIN if single and m != SINGLE_SLICE_PREFERRED else 1.0) for m in REGISTRY}
    ranked = sorted(scores, key=lambda c: c.error * handicap[c.method])
    rejected: list[str] = []
    chosen: Reconstruction | None = None
    for sc in ranked:
        if not np.isfinite(sc.error):
            continue
        rec = fit_rec if sc.method == "fit" else REGISTRY[sc.method].build(full, opts, progress)
        alb, at = max_albedo(rec)
        if alb > 1.0 + ALBEDO_TOLERANCE:
            rejected.append(f"{sc.method} (held-out {sc.error:.2%}) reflects more than it receives: directional "
                            f"albedo {alb:.3g} at theta_i = {at:g} deg")
            continue
        chosen = rec
        break
    if chosen is None:
        raise ReconstructionError(f"{s.source}: no method gives a physically plausible BRDF from these samples ("
                                  + "; ".join(rejected or [f"{c.method}: {c.failure}" for c in scores]) + ")")
    best = next(c for c in ranked if c.method == chosen.method)
    others = ", ".join(f"{c.method} {c.error:.2%}" for c in ranked if c is not best and np.isfinite(c.error))
    model = f" ({fit_rec.result.name})" if chosen.method == "fit" else ""
    reason = (f"lowest held-out error ({scheme}): {chosen.method}{model} predicts the samples it did not see to "
              f"{best.error:.2%} relative RMSE of f cos cos" + (f" (then {others})" if others else ""))
    if single:
        reason += (f"; with one incidence {SINGLE_SLICE_PREFERRED} is preferred unless another method predicts "
                   f"{SINGLE_SLICE_MARGIN:g} times better (one slice cannot show a model's extrapolation in theta_d)")
    if rejected:
        reason += "; not used: " + "; ".join(rejected)
    if s is not full:
        scheme += f", on {len(s)} of the {len(full)} samples"
    cv = {"scheme": scheme, "folds": len(masks), "metric": "relative RMSE of f cos(theta_i) cos(theta_o) over the "
          "held-out samples" + (" inside the scene's ranges" if inside is not None else ""),
          "scores": [c.as_dict() for c in sorted(scores, key=lambda c: c.error)], "chosen": chosen.method,
          "fit_model": fit_rec.result.name, "rejected": rejected,
          "single_incidence_preference": ({"method": SINGLE_SLICE_PREFERRED, "margin": SINGLE_SLICE_MARGIN}
                                          if single else None)}
    return chosen, {"requested": "auto", "used": chosen.method, "reason": reason, "cross_validation": cv,
                    "held_out_predictions": ({} if s is not full else  # per sample of the input (none when thinned)
                                             {c.method: c.predictions for c in scores if c.predictions is not None})}


def reconstruct(s: Slice, method: str = "auto", opts: Options | None = None,
                progress: Callable[[str], None] | None = None) -> tuple[Reconstruction, dict[str, Any]]:
    """Reconstruct ``s`` (f_r, grey or RGB) with ``method`` (``auto`` or a registered name); returns
    (reconstruction, choice) where choice holds ``requested``, ``used``, ``reason`` (and ``cross_validation``
    for ``auto``)."""
    opts = opts or Options()
    check_slice(s)  # too few samples, NaN/inf, all zero, duplicates: a clear error before any method runs
    s = s.sorted()  # by (theta_i, theta_o): the order the methods expect (captures may be in any order)
    if method == "auto":
        return _auto(s, opts, progress)
    rec = get(method).build(s, opts, progress)
    return rec, {"requested": method, "used": rec.method, "reason": f"requested with --method {method}"}


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
