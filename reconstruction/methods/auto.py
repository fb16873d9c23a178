"""``auto``: every usable method cross-validated on the measured samples, the one that predicts best chosen.

``auto`` chooses by prediction, never by a method's residual on its own samples:

1. ``fit`` is run on all samples (its model is chosen by BIC, honouring ``--scene``);
2. every registered method (``fit`` with that model structure, ``microfacet``, ``revolve``, ``bivariate``) is
   cross-validated on the measured samples (:mod:`reconstruction.methods.crossval`: leave-one-incidence-out with several
   incidences, held-out contiguous blocks of theta_o with one). With ``--scene`` only the held-out samples inside
   the scene's ranges count; when the scene's budget replaced the BIC choice by a simpler model (fitted to the
   scene's samples, and so refitted in every fold), the BIC choice competes too, so that a scene never makes the
   choice worse, and a choice whose held-out error exceeds the budget is said (``over_budget``, a warning);
3. the method with the lowest held-out **image error** (the held-out samples tone-mapped as the pixels of a
   point-lit sphere, :mod:`reconstruction.methods.crossval`) whose BRDF is physically plausible (directional
   albedo <= 1 + tolerance at every incidence) is used; the relative RMSE of f cos cos is reported beside it.
   The relative RMSE, which the specular peak's values dominate, ignores the dim off-specular level that covers
   most of a rendered sphere; docs/real-materials.md has the benchmark figures of the change. One slice of point
   readings has no preferred method (``bivariate`` was preferred by a margin of 2 while the ranking was by the
   relative RMSE; by the image error the preference lowered the median PSNR on the real materials)
   (:func:`preference`). One slice read through a finite aperture (the slice's ``instrument``) prefers
   ``microfacet`` (:data:`SINGLE_SLICE_APERTURE_MARGIN`: held-out cone averages cannot show the
   cone's blur that an interpolating method writes into the table), unless ``fit``'s model explains the slice
   (held-out relative RMSE at most :data:`SINGLE_SLICE_FIT_EXPLAINS`): then ``fit`` and ``microfacet`` are
   preferred, ``fit`` of the two (:data:`SINGLE_SLICE_FIT_MARGIN`: one slice cannot separate microfacet's
   tabulated distribution from its Fresnel factor, so both predict the slice alike while microfacet's table can
   be far off at the incidences the slice never saw; a model that explains the slice carries its physics there).
   With a prior of measured materials
   (``--prior``), ``prior`` is the preferred method instead, by :data:`PRIOR_MARGIN_SINGLE` from one slice and
   :data:`PRIOR_MARGIN_SEVERAL` from several; its variants anchored to the bivariate interpolation
   (:data:`PRIOR_ANCHORS`) are scored from the two methods' held-out predictions and compete as ``prior``. No
   preference applies when the best method predicts to within :data:`NOISE_LEVEL_FACTOR` of the samples' own noise.

The report's ``cross_validation`` section holds the scheme, every method's held-out error and the choice.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable, Iterator
from contextvars import ContextVar
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.base import Reconstruction, ReconstructionError
from reconstruction.core.checks import ALBEDO_INCIDENCES_DEG, ALBEDO_TOLERANCE, checked_albedo
from reconstruction.core.samples import PointFolds, everywhere, points_anywhere, scans_hemisphere
from reconstruction.core.slicedata import Slice
from reconstruction.executor import Background as _Background
from reconstruction.executor import forked, release_spare_core
from reconstruction.methods import REGISTRY, Options, get
from reconstruction.methods.crossval import (
    CVScore,
    SceneBudgetWarning,
    budget_check,
    cross_validate,
    folds,
    noise_level,
    scene_mask,
    score_predictions,
    sweep_folds,
)

__all__ = ["reconstruct_auto", "max_albedo", "thin_for_cv", "preference", "at_noise_level", "rank", "import_methods",
           "start_child"]

CV_MAX_SAMPLES = 3000
#: With points anywhere on the hemisphere at several incidences (a Zemax or RGL file) auto prefers ``bivariate``,
#: which places every point by its (theta_h, theta_d, phi_d) and so reproduces the measured hemispheres, unless
#: another method predicts the held-out incidences this many times better: a table is read mostly between
#: measured incidences, while whole incidences held out ask for an extrapolation across theta_i that a real
#: measurement may not support (on the real Speos-converted file of docs/formats.md every method predicts its
#: held-out incidences to 88-1650 % while bivariate reproduces the points to 16 % and microfacet, chosen without
#: this, to 99 %); an exact model (fit of a lambert + ggx file, about 0 % held out) still wins by far.
HEMISPHERE_PREFERRED = ("bivariate",)
HEMISPHERE_MARGIN = 2.0
#: most points anywhere cross-validated on (every in-plane point and an even random subset of the rest)
CV_MAX_POINTS = 3000
CV_MAX_INCIDENCES = 24
#: From one slice read through a finite aperture (a detector cone or a divergent source: the slice metadata's
#: ``instrument``) auto prefers ``microfacet`` instead, by this margin: every reading, the held-out ones included, is
#: a cone average, so cross-validation cannot show that an interpolating method carries the cone's blur of the peak
#: into the table, while microfacet fits its lobes as the cone reads them. Chosen on the physical-instrument study
#: of the 48 MERL materials (docs/study.md, measured materials: 1 deg cone, one slice at 40 deg; auto's median rmse80
#: 57.5 % with bivariate preferred, 45.9 % with this, microfacet alone 43.3 %), so tuned to them.
SINGLE_SLICE_APERTURE_PREFERRED = ("microfacet",)
SINGLE_SLICE_APERTURE_MARGIN = 3.0
#: ... unless fit's model explains the slice: fit's held-out relative RMSE of f cos cos at most this. Then
#: :data:`SINGLE_SLICE_EXPLAINED_PREFERRED` (fit too fits its lobes as the cone reads them), fit of the two unless
#: microfacet predicts :data:`SINGLE_SLICE_FIT_MARGIN` times better. Every sample of one slice lies on theta_d =
#: theta_i +- theta_h, so microfacet's tabulated distribution and its fitted Fresnel index trade against each
#: other: on the quick study's glossy-ggx (lambert + ggx with Fresnel, one slice at 30 deg, 1 deg cone; issue 41)
#: both predicted the held-out blocks alike (fit 0.0036 / 0.45 %, microfacet 0.0025 / 0.61 % image error /
#: relative RMSE) while microfacet's index came out 2.85 for 1.5 and its table 71 % off against fit's 0.7 %
#: (2 deg adaptive: 79 % against 16.7 %; fit held out 0.48 %). On the 48 MERL materials of the reduced real-materials
#: study (one slice, the same cone) fit's held-out error is 0.84-74 % (median 11 %) and its table mostly worse than
#: microfacet's (pure-rubber 0.84 %: 45 % against 29 %; orange-paint 1.1 %: 63 % against 14 %): none is within
#: this, so their choice is unchanged. A threshold between the two sets, so tuned to them.
SINGLE_SLICE_FIT_EXPLAINS = 0.007
SINGLE_SLICE_EXPLAINED_PREFERRED = ("fit", "microfacet")
SINGLE_SLICE_FIT_MARGIN = 2.0
#: With a prior of measured materials (``--prior``) auto prefers ``prior`` unless another method predicts the
#: held-out samples this many times better: from one slice, and from several (leave-one-incidence-out then sees
#: the extrapolation across theta_i that one slice cannot). Chosen on the 48 MERL materials of
#: benchmarks/bench_real_materials.py (see docs/real-materials.md): from several slices 2 rather than 1.5 once
#: grazing cases (20/50/75 and 40/70 deg) were measured beside 20/40/60 (median rmse80 16.8 / 15.4 / 17.2 % against
#: 19.9 / 15.5 / 18.7 %; within 10 % of the best method on 96 of the 144 cases against 89).
PRIOR_MARGIN_SINGLE = 4.0
PRIOR_MARGIN_SEVERAL = 2.0
#: ... unless the best method predicts the held-out samples within this factor of the samples' own noise
#: (:func:`reconstruction.methods.crossval.noise_level`): a model that explains all the data can show is taken as is (a
#: lambert + ggx slice with 1 % noise: fit 1.3 % from one slice, where prior's 4x margin would have taken 17 %).
NOISE_LEVEL_FACTOR = 1.5
#: The anchors of ``prior`` that auto scores (:class:`reconstruction.methods.prior.AnchoredPrior`: f_prior^(1-a)
#: f_bivariate^a), each from the held-out predictions of prior and bivariate (no further fits). On the 48 MERL
#: materials (benchmarks/bench_real_materials.py) they cut auto's worst rmse80 from one slice from 146 % to 99 %
#: and from 20/40/60 deg from 169 % to 86 %; the medians move by about a point either way (28.0 -> 27.3 %,
#: 16.8 -> 18.0 %, 15.4 -> 16.4 % from 20/50/75, 17.2 -> 15.4 % from 40/70; README: Real materials).
PRIOR_ANCHORS = (0.25, 0.5)
#: The methods cross-validated beside fit's model search (when the machine has two cores): in the run's forked child
#: (:class:`reconstruction.executor.Forked`: their fits hold the GIL) when there is one, else in a second thread.
BACKGROUND_METHODS = ("microfacet", "revolve", "bivariate")

def max_albedo(rec: Reconstruction) -> tuple[float, float]:
    """(largest directional albedo over channels and theta_i = 0-85 deg, the theta_i in degrees where it is).

    Integrated as the written table's check integrates (:func:`reconstruction.core.checks.checked_albedo`), on a
    coarser 48 x 96 hemisphere grid: the half vector where the grid exceeds 1 + tolerance (a mirror-like lobe
    aliases on it)."""
    alb, _ = checked_albedo(rec.eval, 48, 96)
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


def preference(methods: list[str], single: bool, aperture: bool = False, anywhere: bool = False,
               fit_error: float = math.inf) -> tuple[list[str], float]:
    """(the preferred methods, the factor by which another must predict better to be chosen over them) among
    ``methods``: ``prior`` when it is there (:data:`PRIOR_MARGIN_SINGLE` from one slice,
    :data:`PRIOR_MARGIN_SEVERAL` from several), else with points ``anywhere`` on the hemisphere
    :data:`HEMISPHERE_PREFERRED`, else from one slice read through a finite ``aperture``
    :data:`SINGLE_SLICE_APERTURE_PREFERRED`, or :data:`SINGLE_SLICE_EXPLAINED_PREFERRED` when ``fit_error`` (fit's
    held-out relative RMSE) is at most :data:`SINGLE_SLICE_FIT_EXPLAINS`; none else (one slice of point readings
    included: module doc)."""
    if "prior" in methods:  # measured materials know what one slice cannot show
        return ["prior"], PRIOR_MARGIN_SINGLE if single else PRIOR_MARGIN_SEVERAL
    if anywhere and not single:
        return [m for m in HEMISPHERE_PREFERRED if m in methods], HEMISPHERE_MARGIN
    if single and aperture:
        kept = SINGLE_SLICE_EXPLAINED_PREFERRED if fit_error <= SINGLE_SLICE_FIT_EXPLAINS else \
            SINGLE_SLICE_APERTURE_PREFERRED
        return [m for m in kept if m in methods], SINGLE_SLICE_APERTURE_MARGIN
    return [], 1.0


def at_noise_level(scores: list[CVScore], preferred: list[str], noise: float) -> bool:
    """True when a method is preferred and the best held-out error is within :data:`NOISE_LEVEL_FACTOR` of
    ``noise`` (the error the samples' own noise amounts to): the preference then does not apply."""
    best = min((c.error for c in scores), default=math.inf)
    return bool(preferred) and noise > 0 and best <= NOISE_LEVEL_FACTOR * noise


def rank(scores: list[CVScore], preferred: list[str], margin: float, noise: float = 0.0) -> list[CVScore]:
    """``scores`` best first: by held-out image error (:attr:`~reconstruction.methods.crossval.CVScore.criterion`),
    that of a method not in ``preferred`` multiplied by ``margin``; by the plain criterion when the best relative
    RMSE is within :data:`NOISE_LEVEL_FACTOR` of ``noise`` (the error the samples' own noise amounts to). Within
    :data:`SINGLE_SLICE_EXPLAINED_PREFERRED`, the methods after the first are multiplied by
    :data:`SINGLE_SLICE_FIT_MARGIN`, and the others by ``margin`` times the weight of the best preferred one (so
    that another method is chosen when it predicts ``margin`` times better than the preferred choice)."""
    if at_noise_level(scores, preferred, noise):
        return sorted(scores, key=lambda c: c.criterion)
    inner = {m: (SINGLE_SLICE_FIT_MARGIN if k else 1.0) for k, m in enumerate(preferred)} \
        if tuple(preferred) == SINGLE_SLICE_EXPLAINED_PREFERRED else dict.fromkeys(preferred, 1.0)
    pref = [c for c in scores if c.method in inner]
    ref = inner[min(pref, key=lambda c: c.criterion * inner[c.method]).method] if pref else 1.0
    return sorted(scores, key=lambda c: c.criterion * (inner[c.method] if c.method in inner
                                                       else margin * ref if preferred else 1.0))


def _finite_aperture(s: Slice) -> bool:
    """True when the slice's readings are averages over a finite detector cone or source divergence."""
    from reconstruction.instrument.response import Instrument, InstrumentError

    try:
        return not Instrument.from_meta(s.meta.get("instrument")).is_point
    except InstrumentError:
        return False  # the methods that use the instrument report the malformed metadata


def reconstruct_auto(s: Slice, opts: Options,
                     progress: Callable[[str], None] | None) -> tuple[Reconstruction, dict[str, Any]]:
    """Cross-validate every usable method on ``s`` (sorted, checked) and build the chosen one on all samples;
    returns (reconstruction, choice) as :func:`reconstruction.pipeline.reconstruct` does. The folds' fits and the
    final one share their cone integrals (a finite aperture's readings of unit lobes, computed once per sample)."""
    from reconstruction.instrument.response import shared_cone_averages

    with shared_cone_averages():
        return _reconstruct_auto(s, opts, progress)


def _reconstruct_auto(s: Slice, opts: Options,
                      progress: Callable[[str], None] | None) -> tuple[Reconstruction, dict[str, Any]]:
    full = s
    pts = points_anywhere(full)
    # cross-validation of a large input on a subsample; the chosen method uses every sample. Points anywhere (a
    # hemispherical file) are cross-validated as points: whole incidences held out, every method (revolve on the
    # in-plane points of the training incidences) predicting every held-out point
    s = PointFolds.of(everywhere(full, CV_MAX_POINTS)) if pts is not None else thin_for_cv(full)
    hemisphere = pts is not None and scans_hemisphere(pts)
    # a bench's sweeps out of the plane (a tilted sample): the in-plane folds as without them, then each such sweep
    scheme, masks = sweep_folds(s) if pts is not None and not hemisphere else folds(s)  # type: ignore[arg-type]
    if pts is not None:
        scheme += f" over points anywhere ({len(s)} of the {len(pts)} points)"
    inside = scene_mask(s, opts.scene)
    if inside is not None and not inside.any():
        inside = None  # no sample inside the scene: judge on all of them
    fit_rec, scores, names, built = _score_methods(s, full, opts, masks, inside, progress)
    scores += _anchored_scores(s, scores, masks, inside)
    single = np.unique(s.theta_i_deg).size == 1
    fit_error = min((c.error for c in scores if c.method == "fit"), default=math.inf)
    # bivariate's grid is preferred for scans of whole hemispheres, not for a bench's sweeps out of the plane (a
    # tilted sample): from a few great circles its grid fills the rest by smoothing (docs/real-materials.md)
    preferred, margin = preference(names, single, _finite_aperture(s), hemisphere, fit_error)
    noise = noise_level(s, inside)
    ranked = rank(scores, preferred, margin, noise)
    at_noise = at_noise_level(scores, preferred, noise)
    chosen, best, rejected = _choose(s, full, opts, fit_rec, ranked, scores, progress)
    rest = [c for c in ranked[ranked.index(best) + 1:] if np.isfinite(c.error)]

    def fallbacks() -> Iterator[tuple[str, Reconstruction]]:
        """The next methods in auto's order, built on all samples: what the pipeline writes instead when the
        chosen method's table fails a plausibility check (the check of the written table is finer than
        :func:`max_albedo`)."""
        for sc in rest:  # a handful
            yield sc.label, (_bic_fit(full, opts, fit_rec, progress) if sc.method == "fit" and sc.variant
                             else fit_rec if sc.method == "fit"
                             else REGISTRY[sc.method].build(full, _options_of(sc, opts), progress))

    reason = _reason(scheme, chosen, best, ranked, rejected, preferred, margin, single, at_noise, noise)
    budget = budget_check(opts.scene, best, scores, noise)
    if budget.get("over_budget"):
        reason += "; " + budget["over_budget_warning"]
        warnings.warn(SceneBudgetWarning(f"{s.source}: {budget['over_budget_warning']}"), stacklevel=2)
    if s is not full and pts is None:
        scheme += f", on {len(s)} of the {len(full)} samples"
    cv = _cv_section(scheme, masks, inside, scores, chosen, best, fit_rec, rejected, budget, preferred, margin,
                     single, at_noise, noise)
    return chosen, {"requested": "auto", "used": chosen.method, "reason": reason, "cross_validation": cv,
                    "fallbacks": fallbacks, **({"built": built} if built is not None else {}),
                    "held_out_predictions": ({} if s is not full else  # per sample of the input (none when thinned)
                                             {c.method: c.predictions for c in reversed(scores)
                                              if c.predictions is not None and (c.method != best.method or c is best)})}


def _score_methods(s: Slice, full: Slice, opts: Options, masks: list[Any], inside: Any,
                   progress: Callable[[str], None] | None
                   ) -> tuple[Any, list[CVScore], list[str], Callable[[], dict[str, Reconstruction]] | None]:
    """fit on all samples and every usable method's held-out score on ``s``: (fit's reconstruction, the scores,
    the methods' names in the registry's order, the forked child's builds of its methods or None)."""
    from reconstruction.methods.fit import FitReconstruction, model_name, reconstruct_fit

    # microfacet, revolve and bivariate do not depend on fit's choice: they are cross-validated in the run's forked
    # child (or a second thread) while fit searches its model on all samples; this thread's helper waits for them.
    # prior stays in this thread, after fit: its large least-squares problems use BLAS threads, whose number fit's
    # threadpool limit changes for the whole process while it runs (and with it the last digits of prior's results)
    others = [(name, lambda tr, m=m: m.build(tr, opts, None)) for name, m in REGISTRY.items()
              if name in BACKGROUND_METHODS and m.usable(opts)]
    child = forked()
    with _Background(enabled=len(others) > 0) as bg:
        built: Callable[[], dict[str, Reconstruction]] | None = None
        if child is not None and others:  # in the run's forked child (their fits hold the GIL), this thread waiting
            answer = bg.submit(child.submit(_cross_validate_methods, s, [n for n, _ in others], opts, masks, inside))
            pending = {name: (lambda name=name: answer()[name]) for name, _ in others}
            if KEEP_BUILDS.get():  # then, in the child, the same methods on all samples: asked for when drawn
                built = child.submit(_build_methods, full, [n for n, _ in others], opts)
        else:
            pending = {name: bg.submit(cross_validate, s, name, build, masks, inside) for name, build in others}
        bg.submit(release_spare_core)  # then the core is free for the work that waits for it (the posterior)
        fit_rec = get("fit").build(full, opts, progress)
        assert isinstance(fit_rec, FitReconstruction)
        specs = fit_rec.result.specs
        # (method, variant, builder of a training slice): fit refitted in every fold as it was fitted to all samples
        # (to a scene's samples when its budget chose a simpler model), and then the BIC choice competes too
        builders: list[tuple[str, str | None, Callable[[Slice], Reconstruction]]] = []
        for name, m in REGISTRY.items():
            if not m.usable(opts):
                continue
            if name == "fit":
                builders.append((name, None, lambda tr: reconstruct_fit(
                    everywhere(tr), scene=opts.scene, lobes=opts.lobes, specs=specs,
                    fit_to_scene=fit_rec.fitted_to_scene)))
                if fit_rec.bic_specs is not None:
                    builders.append((name, f"BIC choice {model_name(fit_rec.bic_specs)}", lambda tr: reconstruct_fit(
                        everywhere(tr), scene=opts.scene, lobes=opts.lobes, specs=fit_rec.bic_specs)))
            elif name == "prior":  # its anchored variants are scored from its and bivariate's held-out predictions
                builders.append((name, None, lambda tr, m=m: m.build(tr, opts.replace(prior_anchor=0.0),
                                                                     None)))
            elif name in pending:
                builders.append((name, None, lambda tr: None))  # cross-validated beside fit (above)
            else:
                builders.append((name, None, lambda tr, m=m: m.build(tr, opts, None)))
        scores: list[CVScore] = []
        for name, variant, build in builders:  # a handful of methods, in the registry's order
            if progress:
                progress(f"cross-validating {name}" + (f" ({variant})" if variant else ""))
            sc = pending[name]() if name in pending else cross_validate(s, name, build, masks, inside)
            sc.anchor = 0.0 if name == "prior" else None  # built with anchor 0 (above)
            sc.variant = variant
            scores.append(sc)
    return fit_rec, scores, [b[0] for b in builders], built


def _choose(s: Slice, full: Slice, opts: Options, fit_rec: Any, ranked: list[CVScore], scores: list[CVScore],
            progress: Callable[[str], None] | None) -> tuple[Reconstruction, CVScore, list[str]]:
    """The best-ranked method whose reconstruction on all samples reflects no more than it receives: (it, its
    score, why the better-ranked ones were not used)."""
    rejected: list[str] = []
    chosen: Reconstruction | None = None
    best = ranked[0]
    for sc in ranked:
        if not np.isfinite(sc.error):
            continue
        rec = (fit_rec if sc.method == "fit" and not sc.variant else _bic_fit(full, opts, fit_rec, progress)
               if sc.method == "fit" else REGISTRY[sc.method].build(full, _options_of(sc, opts), progress))
        alb, at = max_albedo(rec)
        if alb > 1.0 + ALBEDO_TOLERANCE:
            rejected.append(f"{sc.label} (held-out {sc.error:.2%}) reflects more than it receives: directional "
                            f"albedo {alb:.3g} at theta_i = {at:g} deg")
            continue
        chosen, best = rec, sc
        break
    if chosen is None:
        raise ReconstructionError(f"{s.source}: no method gives a physically plausible BRDF from these samples ("
                                  + "; ".join(rejected or _reasons(scores)) + ")")
    return chosen, best, rejected


def _reasons(scores: list[CVScore]) -> list[str]:
    """Each method's reason it could not be judged, for a refusal; one line for all when they share it."""
    why = [c.failure or "no finite held-out error" for c in scores]
    if len(set(why)) == 1 and len(why) > 1:
        return [f"{', '.join(c.label for c in scores)}: {why[0]}"]
    return [f"{c.label}: {w}" for c, w in zip(scores, why, strict=True)]


def _reason(scheme: str, chosen: Reconstruction, best: CVScore, ranked: list[CVScore], rejected: list[str],
            preferred: list[str], margin: float, single: bool, at_noise: bool, noise: float) -> str:
    """The report's sentence on why ``chosen`` was chosen."""
    from reconstruction.methods.fit import FitReconstruction

    others = ", ".join(f"{c.label} {_both(c)}" for c in ranked if c is not best and np.isfinite(c.error))
    model = f" ({chosen.result.name})" if isinstance(chosen, FitReconstruction) and not best.variant else ""
    reason = (f"lowest held-out error ({scheme}): {best.label}{model} predicts the samples it did not see to "
              f"{_both(best)} (image error: the samples tone-mapped as a lit sphere's pixels, RMS; relative RMSE of "
              f"f cos cos)" + (f" (then {others})" if others else ""))
    if at_noise:
        reason += (f"; the best predicts to within {NOISE_LEVEL_FACTOR:g}x the samples' own noise ({noise:.2%}), so "
                   "no method is preferred")
    elif preferred and single:
        explained = tuple(preferred) == SINGLE_SLICE_EXPLAINED_PREFERRED
        why = ("a finite aperture: every reading is a cone average, which cross-validation cannot see through"
               if explained or tuple(preferred) == SINGLE_SLICE_APERTURE_PREFERRED else
               "one slice cannot show a model's extrapolation in theta_d")
        reason += (f"; with one incidence {' or '.join(preferred)} is preferred unless another method predicts "
                   f"{margin:g} times better ({why})")
        if explained:
            reason += (f", and {preferred[0]}, whose model explains the slice (held out to at most "
                       f"{SINGLE_SLICE_FIT_EXPLAINS:.1%}), over {', '.join(preferred[1:])} unless it predicts "
                       f"{SINGLE_SLICE_FIT_MARGIN:g} times better (one slice cannot separate microfacet's tabulated "
                       "distribution from its Fresnel factor)")
    elif preferred == ["prior"]:
        reason += (f"; prior (measured materials) is preferred unless another method predicts {margin:g} times "
                   "better")
    elif preferred:
        reason += (f"; with points anywhere on the hemisphere {' or '.join(preferred)} (every point placed by its "
                   f"half/difference angles) is preferred unless another method predicts {margin:g} times better")
    if rejected:
        reason += "; not used: " + "; ".join(rejected)
    return reason


def _cv_section(scheme: str, masks: list[Any], inside: Any, scores: list[CVScore], chosen: Reconstruction,
                best: CVScore, fit_rec: Any, rejected: list[str], budget: dict[str, Any], preferred: list[str],
                margin: float, single: bool, at_noise: bool, noise: float) -> dict[str, Any]:
    """The report's ``cross_validation`` section."""
    cv = {"scheme": scheme, "folds": len(masks), "metric": "image error of the held-out samples (tone-mapped as a "
          "point-lit sphere's pixels, RMS; reconstruction.methods.crossval), relative RMSE of f cos(theta_i) "
          "cos(theta_o) beside it" + (" (those inside the scene's ranges)" if inside is not None else ""),
          "scores": [c.as_dict() for c in sorted(scores, key=lambda c: c.criterion)], "chosen": chosen.method,
          "chosen_label": best.label, **({"prior_anchor": best.anchor or 0.0} if best.method == "prior" else {}),
          "fit_model": fit_rec.result.name, "rejected": rejected, **budget,
          "single_incidence_preference": ({"method": preferred[0], "methods": preferred, "margin": margin}
                                          if single and preferred else None),
          "preference": ({"methods": preferred, "margin": margin, "noise_level": noise, "applied": not at_noise}
                         if preferred else None)}
    return cv


#: Within a run that draws every method (the HTML page: ``pipeline`` sets it), the forked child also builds its
#: methods on all samples once they are cross-validated (beside the run), and auto's choice carries them as
#: ``built``: a function giving {method: reconstruction} (it waits for the child).
KEEP_BUILDS: ContextVar[bool] = ContextVar("auto_keep_builds", default=False)


def _cross_validate_methods(s: Slice, names: list[str], opts: Options, masks: list[NDArray[np.bool_]],
                            inside: NDArray[np.bool_] | None) -> dict[str, CVScore]:
    """{method: its cross-validation} of the registered methods ``names`` (auto's background methods), their cone
    integrals shared: what the run's forked child computes (:class:`reconstruction.executor.Forked`)."""
    from reconstruction.instrument.response import shared_cone_averages

    with shared_cone_averages():
        return {name: cross_validate(s, name, lambda tr, m=REGISTRY[name]: m.build(tr, opts, None), masks, inside)
                for name in names}  # three


def _build_methods(s: Slice, names: list[str], opts: Options) -> dict[str, Reconstruction]:
    """{method: built on ``s``} of the registered methods ``names`` (those that cannot are left out, as the HTML
    page's own builds): the forked child's second task when the page draws every method."""
    built: dict[str, Reconstruction] = {}
    for name in names:  # three
        try:
            built[name] = REGISTRY[name].build(s, opts, None)
        except (ReconstructionError, ValueError):
            pass
    return built


def import_methods() -> None:
    """Import the modules of the methods auto always tries (each registered method's ``modules``; those that need
    an option, as ``prior`` its folder, import theirs when built) and the readers of the inputs: about half a
    second, most of it scipy's optimize and interpolate."""
    import importlib

    for name in ("reconstruction.formats.brdffile", *(mod for m in REGISTRY.values() if m.available is None
                                                      for mod in m.modules)):
        importlib.import_module(name)


def start_child(child: Any, inputs: tuple[str, ...], quantity: str | None, columns: str | None,
                blind_spot_deg: float | None, angles_in: str = "degrees") -> Callable[[], dict[Any, Any]] | None:
    """Give auto's forked child (:class:`reconstruction.executor.Forked`, forked before scipy's import) its first
    work while the run imports the methods: fit's cone tables of the samples
    (:func:`reconstruction.methods.fit.aperture.prefetch_tables`), then the same imports. Returns the tables' getter
    (entries for :func:`reconstruction.instrument.response.seed_shared_cone_averages`), or None when the inputs are
    not slice files (.csv) or cannot be read quietly here (the run reads them again and says what is wrong)."""
    from reconstruction.formats import inputs as readers
    from reconstruction.methods.fit.aperture import prefetch_tables

    seed = None
    if inputs and all(str(p).lower().endswith(".csv") for p in inputs):
        try:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                s = readers.load_inputs(list(inputs), quantity=quantity, columns=readers.parse_columns(columns),
                                        blind_spot_deg=blind_spot_deg, angles_in=angles_in).slice
            seed = child.submit(prefetch_tables, s)
        except Exception:  # noqa: BLE001 - whatever it is, the run itself reads the inputs and says it
            seed = None
    child.submit(import_methods)
    return seed


def _both(c: CVScore) -> str:
    """"0.021 / 5.30 %": a score's image error and relative RMSE, as the reason prints them."""
    return (f"{c.image_error:.3f} / " if math.isfinite(c.image_error) else "") + f"{c.error:.2%}"


def _bic_fit(s: Slice, opts: Options, fit_rec: Any, progress: Callable[[str], None] | None) -> Reconstruction:
    """``fit`` with the BIC choice that a scene's budget replaced by a simpler model, fitted to every sample:
    auto's choice when it predicts the scene's held-out samples better."""
    from reconstruction.core.samples import everywhere
    from reconstruction.methods.fit import reconstruct_fit

    rec = reconstruct_fit(everywhere(s), scene=opts.scene, lobes=opts.lobes, specs=fit_rec.bic_specs,
                          progress=progress)
    rec.info["selection"]["reason"] = (f"the BIC choice, {rec.result.name}, which the scene's budget replaced by "
                                       f"{fit_rec.result.name}: auto found it predicts the scene's held-out "
                                       "samples better")
    if "scene" in fit_rec.info:
        rec.info["scene"] = fit_rec.info["scene"]
    return rec


def _anchored_scores(s: Slice, scores: list[CVScore], masks: list[NDArray[np.bool_]],
                     inside: NDArray[np.bool_] | None) -> list[CVScore]:
    """The held-out scores of prior anchored to bivariate (:data:`PRIOR_ANCHORS`), from the two methods' own
    held-out predictions (the blend of each fold's two predictions is that fold's prediction of the blend)."""
    from reconstruction.methods.prior import anchored

    by = {c.method: c for c in scores}
    p, b = by.get("prior"), by.get("bivariate")
    if (p is None or b is None or p.predictions is None or b.predictions is None or not math.isfinite(p.error)
            or not math.isfinite(b.error)):
        return []
    out = []
    for a in PRIOR_ANCHORS:  # two weights
        sc = score_predictions(s, "prior", anchored(p.predictions, b.predictions, a), masks, inside,
                               p.seconds + b.seconds)
        sc.anchor = a
        out.append(sc)
    return out


def _options_of(sc: CVScore, opts: Options) -> Options:
    """The options that build the method of ``sc``: a prior variant with its anchor (the prior alone when none was
    scored), as cross-validated; ``--prior-anchor`` is for ``--method prior``."""
    return opts.replace(prior_anchor=sc.anchor or 0.0) if sc.method == "prior" else opts
