"""The reconstruction pipeline: method dispatch (through :mod:`reconstruction.methods`), ``auto``, tabulation of the
result, and :func:`run`, the whole way from input files to a table, a preview and a report (a typed :class:`Job`;
``gonio-reconstruct`` and its ``--batch`` call it).

``auto`` chooses by prediction, never by a method's residual on its own samples:

1. ``fit`` is run on all samples (its model is chosen by BIC, honouring ``--scene``);
2. every registered method (``fit`` with that model structure, ``microfacet``, ``revolve``, ``bivariate``) is
   cross-validated on the measured samples (:mod:`reconstruction.crossval`: leave-one-incidence-out with several
   incidences, held-out contiguous blocks of theta_o with one). With ``--scene`` only the held-out samples inside
   the scene's ranges count; when the scene's budget replaced the BIC choice by a simpler model (fitted to the
   scene's samples, and so refitted in every fold), the BIC choice competes too, so that a scene never makes the
   choice worse, and a choice whose held-out error exceeds the budget is said (``over_budget``, a warning);
3. the method with the lowest held-out relative RMSE of f cos cos whose BRDF is physically plausible (directional
   albedo <= 1 + tolerance at every incidence) is used. With a single incidence, held-out samples of the same
   slice cannot show how a method extrapolates to other incidences (its Fresnel rise or shadowing towards
   grazing theta_d), so ``bivariate``, which holds the peak's microfacet content instead of extrapolating a
   model, is preferred unless another method predicts the held-out samples at least twice as well
   (:data:`SINGLE_SLICE_MARGIN`; on the 48 real MERL materials this lowers auto's median table error from one
   slice from 48 % to 41 %, see docs/real-materials.md, and an exact model, such as a simulated lambert + ggx
   material, still wins by far more). One slice read through a finite aperture (the slice's ``instrument``)
   prefers ``microfacet`` instead (:data:`SINGLE_SLICE_APERTURE_MARGIN`: held-out cone averages cannot show the
   cone's blur that an interpolating method writes into the table). With a prior of measured materials
   (``--prior``), ``prior`` is the preferred method instead, by :data:`PRIOR_MARGIN_SINGLE` from one slice and
   :data:`PRIOR_MARGIN_SEVERAL` from several; its variants anchored to the bivariate interpolation
   (:data:`PRIOR_ANCHORS`) are scored from the two methods' held-out predictions and compete as ``prior``. No
   preference applies when the best method predicts to within :data:`NOISE_LEVEL_FACTOR` of the samples' own noise.

The report's ``cross_validation`` section holds the scheme, every method's held-out error and the choice.
"""

from __future__ import annotations

import dataclasses
import math
import os
import time
import warnings
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

import numpy as np
from numpy.typing import NDArray

from . import merl, sharprows
from .base import Reconstruction, ReconstructionError
from .crossval import (
    CVScore,
    SceneBudgetWarning,
    budget_check,
    cross_validate,
    folds,
    noise_level,
    scene_mask,
    score_predictions,
)
from .inputs import check_slice
from .methods import REGISTRY, Options, get
from .report import ALBEDO_INCIDENCES_DEG, ALBEDO_TOLERANCE, checked_albedo
from .slicefile import Slice

Array = NDArray[np.float64]

__all__ = ["METHODS", "Options", "reconstruct", "tabulate", "max_albedo", "Job", "Progress", "run", "ImplausibleError",
           "check_output", "implausible_message"]

METHODS = ("auto", *REGISTRY)
CV_MAX_SAMPLES = 3000
CV_MAX_INCIDENCES = 24
SINGLE_SLICE_PREFERRED = ("bivariate", "prior")
SINGLE_SLICE_MARGIN = 2.0
#: From one slice read through a finite aperture (a detector cone or a divergent source: the slice metadata's
#: ``instrument``) auto prefers ``microfacet`` instead, by this margin: every reading, the held-out ones included, is
#: a cone average, so cross-validation cannot show that an interpolating method carries the cone's blur of the peak
#: into the table, while microfacet fits its lobes as the cone reads them. Chosen on the physical-instrument study
#: of the 48 MERL materials (docs/study-real-materials.md: 1 deg cone, one slice at 40 deg; auto's median rmse80
#: 57.5 % with bivariate preferred, 45.9 % with this, microfacet alone 43.3 %), so tuned to them.
SINGLE_SLICE_APERTURE_PREFERRED = ("microfacet",)
SINGLE_SLICE_APERTURE_MARGIN = 3.0
#: With a prior of measured materials (``--prior``) auto prefers ``prior`` unless another method predicts the
#: held-out samples this many times better: from one slice, and from several (leave-one-incidence-out then sees
#: the extrapolation across theta_i that one slice cannot). Chosen on the 48 MERL materials of
#: benchmarks/bench_real_materials.py (see docs/real-materials.md): from several slices 2 rather than 1.5 once
#: grazing cases (20/50/75 and 40/70 deg) were measured beside 20/40/60 (median rmse80 16.8 / 15.4 / 17.2 % against
#: 19.9 / 15.5 / 18.7 %; within 10 % of the best method on 96 of the 144 cases against 89).
PRIOR_MARGIN_SINGLE = 4.0
PRIOR_MARGIN_SEVERAL = 2.0
#: ... unless the best method predicts the held-out samples within this factor of the samples' own noise
#: (:func:`reconstruction.crossval.noise_level`): a model that explains all the data can show is taken as is (a
#: lambert + ggx slice with 1 % noise: fit 1.3 % from one slice, where prior's 4x margin would have taken 17 %).
NOISE_LEVEL_FACTOR = 1.5
#: The anchors of ``prior`` that auto scores (:class:`reconstruction.prior.AnchoredPrior`: f_prior^(1-a)
#: f_bivariate^a), each from the held-out predictions of prior and bivariate (no further fits). On the 48 MERL
#: materials (benchmarks/bench_real_materials.py) they cut auto's worst rmse80 from one slice from 146 % to 99 %
#: and from 20/40/60 deg from 169 % to 86 %; the medians move by about a point either way (28.0 -> 27.3 %,
#: 16.8 -> 18.0 %, 15.4 -> 16.4 % from 20/50/75, 17.2 -> 15.4 % from 40/70; README: Real materials).
PRIOR_ANCHORS = (0.25, 0.5)

def max_albedo(rec: Reconstruction) -> tuple[float, float]:
    """(largest directional albedo over channels and theta_i = 0-85 deg, the theta_i in degrees where it is).

    Integrated as the written table's check integrates (:func:`reconstruction.report.checked_albedo`), on a
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


def preference(methods: list[str], single: bool, aperture: bool = False) -> tuple[list[str], float]:
    """(the preferred methods, the factor by which another must predict better to be chosen over them) among
    ``methods``: ``prior`` when it is there (:data:`PRIOR_MARGIN_SINGLE` from one slice,
    :data:`PRIOR_MARGIN_SEVERAL` from several), else from one slice :data:`SINGLE_SLICE_PREFERRED` (point
    readings) or, read through a finite ``aperture``, :data:`SINGLE_SLICE_APERTURE_PREFERRED`; none else."""
    if "prior" in methods:  # measured materials know what one slice cannot show
        return ["prior"], PRIOR_MARGIN_SINGLE if single else PRIOR_MARGIN_SEVERAL
    if single and aperture:
        return [m for m in SINGLE_SLICE_APERTURE_PREFERRED if m in methods], SINGLE_SLICE_APERTURE_MARGIN
    if single:
        return [m for m in SINGLE_SLICE_PREFERRED if m in methods], SINGLE_SLICE_MARGIN
    return [], 1.0


def at_noise_level(scores: list[CVScore], preferred: list[str], noise: float) -> bool:
    """True when a method is preferred and the best held-out error is within :data:`NOISE_LEVEL_FACTOR` of
    ``noise`` (the error the samples' own noise amounts to): the preference then does not apply."""
    best = min((c.error for c in scores), default=math.inf)
    return bool(preferred) and noise > 0 and best <= NOISE_LEVEL_FACTOR * noise


def rank(scores: list[CVScore], preferred: list[str], margin: float, noise: float = 0.0) -> list[CVScore]:
    """``scores`` best first: by held-out error, that of a method not in ``preferred`` multiplied by ``margin``;
    by the plain held-out error when the best one is within :data:`NOISE_LEVEL_FACTOR` of ``noise`` (the error the
    samples' own noise amounts to)."""
    if at_noise_level(scores, preferred, noise):
        return sorted(scores, key=lambda c: c.error)
    return sorted(scores, key=lambda c: c.error * (margin if preferred and c.method not in preferred else 1.0))


def _finite_aperture(s: Slice) -> bool:
    """True when the slice's readings are averages over a finite detector cone or source divergence."""
    from .instrument import Instrument, InstrumentError

    try:
        return not Instrument.from_meta(s.meta.get("instrument")).is_point
    except InstrumentError:
        return False  # the methods that use the instrument report the malformed metadata


def _auto(s: Slice, opts: Options, progress: Callable[[str], None] | None) -> tuple[Reconstruction, dict[str, Any]]:
    from .fit import FitReconstruction, model_name, reconstruct_fit

    fit_rec = get("fit").build(s, opts, progress)
    assert isinstance(fit_rec, FitReconstruction)
    specs = fit_rec.result.specs
    full = s
    s = thin_for_cv(full)  # cross-validation of a large input on a subsample; the chosen method uses every sample
    scheme, masks = folds(s)
    # (method, variant, builder of a training slice): fit refitted in every fold as it was fitted to all samples
    # (to a scene's samples when its budget chose a simpler model), and then the BIC choice competes too
    builders: list[tuple[str, str | None, Callable[[Slice], Reconstruction]]] = []
    for name, m in REGISTRY.items():
        if not m.usable(opts):
            continue
        if name == "fit":
            builders.append((name, None, lambda tr: reconstruct_fit(tr, scene=opts.scene, lobes=opts.lobes,
                                                                    specs=specs, fit_to_scene=fit_rec.fitted_to_scene)))
            if fit_rec.bic_specs is not None:
                builders.append((name, f"BIC choice {model_name(fit_rec.bic_specs)}", lambda tr: reconstruct_fit(
                    tr, scene=opts.scene, lobes=opts.lobes, specs=fit_rec.bic_specs)))
        elif name == "prior":  # its anchored variants are scored from its and bivariate's held-out predictions
            builders.append((name, None, lambda tr, m=m: m.build(tr, dataclasses.replace(opts, prior_anchor=0.0),
                                                                 None)))
        else:
            builders.append((name, None, lambda tr, m=m: m.build(tr, opts, None)))
    inside = scene_mask(s, opts.scene)
    if inside is not None and not inside.any():
        inside = None  # no sample inside the scene: judge on all of them
    scores: list[CVScore] = []
    for name, variant, build in builders:  # a handful of methods
        if progress:
            progress(f"cross-validating {name}" + (f" ({variant})" if variant else ""))
        sc = cross_validate(s, name, build, masks, inside)
        sc.anchor = 0.0 if name == "prior" else None  # built with anchor 0 (above)
        sc.variant = variant
        scores.append(sc)
    scores += _anchored_scores(s, scores, masks, inside)
    single = np.unique(s.theta_i_deg).size == 1
    preferred, margin = preference([b[0] for b in builders], single, _finite_aperture(s))
    noise = noise_level(s, inside)
    ranked = rank(scores, preferred, margin, noise)
    at_noise = at_noise_level(scores, preferred, noise)
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
                                  + "; ".join(rejected or [f"{c.method}: {c.failure}" for c in scores]) + ")")
    others = ", ".join(f"{c.label} {c.error:.2%}" for c in ranked if c is not best and np.isfinite(c.error))
    model = f" ({chosen.result.name})" if isinstance(chosen, FitReconstruction) and not best.variant else ""
    reason = (f"lowest held-out error ({scheme}): {best.label}{model} predicts the samples it did not see to "
              f"{best.error:.2%} relative RMSE of f cos cos" + (f" (then {others})" if others else ""))
    if at_noise:
        reason += (f"; the best predicts to within {NOISE_LEVEL_FACTOR:g}x the samples' own noise ({noise:.2%}), so "
                   "no method is preferred")
    elif preferred and single:
        why = ("a finite aperture: every reading is a cone average, which cross-validation cannot see through"
               if preferred == list(SINGLE_SLICE_APERTURE_PREFERRED) else
               "one slice cannot show a model's extrapolation in theta_d")
        reason += (f"; with one incidence {' or '.join(preferred)} is preferred unless another method predicts "
                   f"{margin:g} times better ({why})")
    elif preferred:
        reason += (f"; prior (measured materials) is preferred unless another method predicts {margin:g} times "
                   "better")
    if rejected:
        reason += "; not used: " + "; ".join(rejected)
    budget = budget_check(opts.scene, best, scores, noise)
    if budget.get("over_budget"):
        reason += "; " + budget["over_budget_warning"]
        warnings.warn(SceneBudgetWarning(f"{s.source}: {budget['over_budget_warning']}"), stacklevel=2)
    if s is not full:
        scheme += f", on {len(s)} of the {len(full)} samples"
    cv = {"scheme": scheme, "folds": len(masks), "metric": "relative RMSE of f cos(theta_i) cos(theta_o) over the "
          "held-out samples" + (" inside the scene's ranges" if inside is not None else ""),
          "scores": [c.as_dict() for c in sorted(scores, key=lambda c: c.error)], "chosen": chosen.method,
          "chosen_label": best.label, **({"prior_anchor": best.anchor or 0.0} if best.method == "prior" else {}),
          "fit_model": fit_rec.result.name, "rejected": rejected, **budget,
          "single_incidence_preference": ({"method": preferred[0], "methods": preferred, "margin": margin}
                                          if single and preferred else None),
          "preference": ({"methods": preferred, "margin": margin, "noise_level": noise, "applied": not at_noise}
                         if preferred else None)}
    return chosen, {"requested": "auto", "used": chosen.method, "reason": reason, "cross_validation": cv,
                    "held_out_predictions": ({} if s is not full else  # per sample of the input (none when thinned)
                                             {c.method: c.predictions for c in reversed(scores)
                                              if c.predictions is not None and (c.method != best.method or c is best)})}


def _bic_fit(s: Slice, opts: Options, fit_rec: Any, progress: Callable[[str], None] | None) -> Reconstruction:
    """``fit`` with the BIC choice that a scene's budget replaced by a simpler model, fitted to every sample:
    auto's choice when it predicts the scene's held-out samples better."""
    from .fit import reconstruct_fit
    from .samples import everywhere

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
    from .prior import anchored

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
    return dataclasses.replace(opts, prior_anchor=sc.anchor or 0.0) if sc.method == "prior" else opts


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


def tabulate(rec: Reconstruction, supersample: tuple[int, int, int] | str | None = None,
             info: dict[str, Any] | None = None) -> Array:
    """The MERL table (3, 90, 90, 180) of ``rec``: bin-centre values, or cell averages with ``supersample``
    ((nh, nd, np) or "adaptive", see :func:`reconstruction.merl.tabulate`).

    Uses the method's own fast ``table()`` for bin centres when it has one; otherwise ``merl.tabulate``. Where the
    method names a lobe narrower than the cells (``sharp_theta_h_rad``), the rows holding it are cell averages over
    theta_h, each theta_d row scaled to the lobe's energy as table readers see it
    (:func:`reconstruction.sharprows.renormalise`; its figures go into ``info`` when given).
    Raises :class:`ReconstructionError` if a cell above the horizon is not finite or is negative.
    """
    fast = getattr(rec, "table", None)
    sharp = getattr(rec, "sharp_theta_h_rad", None)  # a lobe narrower than the cells near theta_h = 0
    if supersample is None and callable(fast):
        t = fast()  # the method's own table (its own theta_h cell averages where a lobe is sharper than the cells)
    else:
        t = merl.tabulate(rec.eval, supersample=supersample)
        if supersample is None and sharp:
            t, _ = merl.average_theta_h_cells(rec.eval, t, sharp, n=8)
    if supersample is None and sharp:  # those rows keep the lobe's energy as table readers see it
        t, figures = sharprows.renormalise(rec.eval, t, sharp)
        if info is not None:
            info.update(figures)
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


# --- the end-to-end pipeline: input files -> table, preview, report ---------------------------------------------


class ImplausibleError(ReconstructionError):
    """The reconstruction fails a plausibility check; nothing was written."""


@dataclass(frozen=True)
class Job:
    """One reconstruction, from input files to outputs: what one ``gonio-reconstruct`` command line asks.

    ``inputs``: slice files or generic tables (merged); ``out``: the MERL table (``.binary``); ``preview``: an
    ``.exr`` (and the PNG beside it); ``report``: the JSON report. The other fields are the command's flags of the
    same names (angles in degrees): ``columns`` as ``"theta_i=NAME,theta_o=NAME"``, ``lobes`` as kinds,
    ``axis`` / ``smoothing`` for revolve, ``supersample`` as (nh, nd, np) or ``"adaptive"``.
    """

    inputs: tuple[str, ...]
    out: str
    method: str = "auto"
    preview: str | None = None
    report: str | None = None
    supersample: tuple[int, int, int] | str | None = None
    quantity: str | None = None
    columns: str | None = None
    blind_spot_deg: float | None = None
    illuminant: str = "D65"
    scene: str | None = None
    lobes: tuple[str, ...] | None = None
    fill: str = "interpolate"
    axis: str = "auto"
    smoothing: float | None = None
    allow_implausible: bool = False
    html: str | None = None
    # other formats (reconstruction.exports; README: Formats); ``out`` may be "" when one of them is asked for
    rgl: str | None = None
    zemax: str | None = None
    zemax_incidences: str | None = None
    zemax_azimuths: str | None = None
    zemax_radials: str | None = None
    export_mitsuba: str | None = None
    export_json: str | None = None
    preview_renderer: str = "builtin"
    prior: str | None = None  # --prior DIR: the folder of prior materials (method prior; auto tries it when given)
    prior_anchor: float = 0.0  # --prior-anchor A: method prior's blend with the bivariate interpolation (0..1)

    @property
    def steps(self) -> list[str]:
        """The steps :func:`run` reports to its ``progress`` (for a progress bar's total)."""
        return (["read", "colour", "reconstruct", "tabulate", "write", "checks"] + (["preview"] if self.preview else [])
                + (["html"] if self.html else []))


class Progress(Protocol):
    """What :func:`run` tells about its progress: a step (or a sub-step, a method being fitted) begins; one of
    :attr:`Job.steps` is done."""

    def begin(self, label: str) -> None: ...

    def done(self, step: str) -> None: ...


def check_output(path: Path, suffix: str | None, flag: str) -> None:
    """An output path must name a file (``suffix``) in an existing, writable folder; checked before any work."""
    if suffix is not None and path.suffix.lower() != suffix:
        raise ReconstructionError(f"{flag} {path}: expected a file name ending in {suffix}")
    if path.is_dir():
        raise ReconstructionError(f"{flag} {path}: is a folder; give a file name"
                                  + (f" ending in {suffix}" if suffix else ""))
    parent = path.parent if str(path.parent) else Path(".")
    if not parent.is_dir():
        raise ReconstructionError(f"{flag} {path}: the folder {parent} does not exist")
    if not os.access(parent, os.W_OK | os.X_OK):
        raise ReconstructionError(f"{flag} {path}: the folder {parent} is not writable")
    if path.exists() and not path.is_file():
        raise ReconstructionError(f"{flag} {path}: exists and is not a regular file")


def implausible_message(method: str, checks: dict[str, Any]) -> str:
    """One line: which plausibility checks of ``checks`` failed, with figures, and what to try."""
    why = []
    if not checks["non_negative"]["pass"]:
        c = checks["non_negative"]
        why.append(f"non_negative: {c['missing_cells']} cell(s) without a value, minimum {c['min_1_per_sr']:.3g} 1/sr")
    if not checks["albedo"]["pass"]:
        c = checks["albedo"]
        alb = np.asarray(c["albedo"], dtype=np.float64)
        k = int(np.argmax(alb.max(axis=1)))
        why.append(f"albedo: the table reflects more light than it receives (directional albedo {alb.max():.3g} > "
                   f"1 + {c['tolerance']:g} at theta_i = {c['theta_i_deg'][k]:g} deg)")
    if not checks["reciprocity"]["pass"]:
        why.append(f"reciprocity: relative error {checks['reciprocity']['relative_error']:.3g}")
    return (f"method {method}: the table fails the plausibility check(s) " + "; ".join(why)
            + "; nothing written. Try --method fit or microfacet (energy-conserving by construction), slices at "
              "more incidences, or --allow-implausible to write it anyway")


def _check_outputs(job: Job) -> None:
    from . import exports

    if job.out:
        check_output(Path(job.out), ".binary", "--out")
    elif not exports.asks_output(job):
        raise ReconstructionError("give --out MATERIAL.binary (or another output: --preview, --html, --report, --rgl, "
                                  "--zemax, --export-mitsuba, --export-json)")
    exports.check_arguments(job)
    if job.preview:
        check_output(Path(job.preview), ".exr", "--preview")
        png = Path(job.preview).with_suffix(".png")
        if png.is_dir():
            raise ReconstructionError(f"--preview {job.preview}: {png} (the PNG beside it) is a folder")
    if job.report:
        check_output(Path(job.report), None, "--report")
    if job.html:
        check_output(Path(job.html), ".html", "--html")


def run(job: Job, progress: Progress | None = None) -> dict[str, Any]:
    """Reconstruct ``job``: read and merge the inputs, convert colour, reconstruct with the job's method (through
    the registry), tabulate, check plausibility, write the table (atomically), the preview and the report.
    Returns the report. Raises :class:`ImplausibleError` (nothing written) for a table that fails a plausibility
    check unless ``job.allow_implausible``; bad input is a :class:`ReconstructionError` (or a reader's error)
    naming the file, checked output paths before any work."""
    from . import colour, exports, inputs, merl, preview, report, zemax
    from .scene import LOBE_KINDS, load_scene

    _check_outputs(job)
    out = Path(job.out) if job.out else None
    lobes = list(job.lobes) if job.lobes else None
    if lobes:
        unknown = [x for x in lobes if x not in LOBE_KINDS]
        if unknown:
            raise ReconstructionError(f"--lobes: unknown kind(s) {unknown}; expected {', '.join(LOBE_KINDS)}")
    timings: dict[str, float] = {}

    def begin(label: str) -> float:
        if progress is not None:
            progress.begin(label)
        return time.perf_counter()

    def done(step: str, t0: float) -> None:
        timings[step] = time.perf_counter() - t0
        if progress is not None:
            progress.done(step)

    t0 = begin("reading inputs")
    loaded = zemax.load_inputs(list(job.inputs), job.quantity, job.columns) or inputs.load_inputs(
        list(job.inputs), quantity=job.quantity, columns=inputs.parse_columns(job.columns),
        blind_spot_deg=job.blind_spot_deg)
    scene = None
    if job.scene:
        sp = Path(job.scene)
        if sp.exists() and not sp.is_file():
            raise ReconstructionError(f"--scene {sp}: not a regular file, expected a scene file (TOML)")
        try:
            scene = load_scene(sp)
        except RecursionError:
            raise ReconstructionError(f"--scene {sp}: invalid TOML: nested too deeply") from None
    done("read", t0)
    t0 = begin("colour")
    try:
        working, colour_info = colour.to_working_channels(loaded.slice, job.illuminant)
    except ReconstructionError as e:  # e.g. spectral channels outside the observer: say which input
        raise ReconstructionError(f"{', '.join(loaded.files)}: {e}") from None
    done("colour", t0)
    t0 = begin("reconstructing")
    opts = Options(scene=scene, fill=job.fill, lobes=lobes, revolve_axis=job.axis, revolve_smoothing=job.smoothing,
                   prior=job.prior, prior_anchor=job.prior_anchor)
    rec, choice = reconstruct(working, job.method, opts,
                              progress=(lambda name: progress.begin(f"fitting {name}")) if progress else None)
    done("reconstruct", t0)
    t0 = begin("tabulating" + (f" (supersample {job.supersample})" if job.supersample else ""))
    energy: dict[str, Any] = {}
    table = tabulate(rec, job.supersample, energy)
    done("tabulate", t0)
    t0 = begin("plausibility checks")
    checks = report.plausibility(rec, table)
    done("checks", t0)
    if not checks["all_pass"] and not job.allow_implausible:
        raise ImplausibleError(implausible_message(rec.method, checks))
    t0 = begin("writing table")
    outputs: dict[str, Any] = {}
    if out is not None:
        merl.write(out, table, require_above_horizon=True)
        outputs.update({"table": str(out), "table_bytes": out.stat().st_size})
    outputs.update(exports.write_outputs(job, rec, timings))
    done("write", t0)
    if job.preview:
        t0 = begin("preview")
        outputs["preview"] = (exports.mitsuba_preview(job, rec, outputs) if job.preview_renderer == "mitsuba"
                              else preview.write_preview(job.preview, table))
        done("preview", t0)
    rep = report.build_report(
        rec=rec, choice=choice, working=working, table=table, checks=checks,
        inputs={"files": loaded.files, "quantities": loaded.quantities, "notes": loaded.notes,
                "columns": job.columns, "scene": job.scene},
        colour=colour_info,
        table_info={"cells": 3 * merl.N_CELLS,
                    "values": "cell averages" if job.supersample else getattr(rec, "table_values", "bin centres")
                    + ("; " + sharprows.DESCRIPTION if energy else ""),
                    **({"sharp_rows": energy} if energy else {}),
                    "supersample": (list(job.supersample) if isinstance(job.supersample, tuple)
                                    else job.supersample),
                    "bin_centres": "theta_h = ((i + 0.5) / 90)^2 * 90 deg, theta_d = j + 0.5 deg, "
                                   "phi_d = k + 0.5 deg"},
        outputs=outputs, timings=timings, dropped_blind_spot=loaded.dropped_blind_spot)
    if not checks["all_pass"]:
        rep["implausible_table_written"] = "written with --allow-implausible: " + implausible_message(rec.method,
                                                                                                      checks)
    if job.html:
        outputs["html"] = str(job.html)
        rep["outputs"]["html"] = str(job.html)
    if job.report:
        outputs["report"] = str(job.report)
        rep["outputs"]["report"] = str(job.report)
        report.write_json(job.report, rep)
    if job.html:
        t0 = begin("html report")
        _write_html(job, rep, working, rec, table, choice, opts)
        rep["timings_s"]["html"] = round(time.perf_counter() - t0, 4)
        done("html", t0)
    return rep


def _write_html(job: Job, rep: dict[str, Any], working: Slice, rec: Reconstruction, table: Array,
                choice: dict[str, Any], opts: Options) -> None:
    """The HTML report of ``job``: every other registered method is built on the same samples for comparison."""
    from . import htmlreport

    ordered = working.sorted()
    others: dict[str, Reconstruction] = {}
    for name, m in REGISTRY.items():
        if name != rec.method:
            try:
                others[name] = m.build(ordered, opts, None)
            except (ReconstructionError, ValueError):
                pass
    held = choice.get("held_out_predictions", {}).get(rec.method)
    title = str(working.meta.get("material") or Path(job.out or job.html or "material").stem)
    htmlreport.write_html(job.html, report=rep, working=ordered, rec=rec, table=table, alternatives=others,
                          held_out=held, title=title)
