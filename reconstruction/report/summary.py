"""Plausibility checks and the JSON report of a reconstruction.

Checks (each ``{"pass": bool, ...figures}``):

* ``non_negative``: every table cell above the horizon is finite and >= 0;
* ``albedo``: the directional albedo a(theta_i) = integral of f cos(theta_o) d omega_o of the written table
  (trilinear lookup, Gauss-Legendre 64 x 128 over the hemisphere) is <= 1 + 0.01 (quadrature tolerance) at
  theta_i = 0, 5, ..., 85 deg, in every channel;
* ``reciprocity``: max |f(wi, wo) - f(wo, wi)| / max |f| of the method's own BRDF over 4096 random pairs is
  <= 1e-6 (the table itself is reciprocal by construction: phi_d and phi_d + pi share a cell).

Top-level report keys: ``method`` (the method used), ``method_requested``, ``method_reason``, ``parameters``,
``residuals``, ``coverage``, ``checks``, ``inputs``, ``colour``, ``table``, ``outputs``, ``timings_s``,
``details`` (everything the method reported) and, for ``--method auto``, ``cross_validation`` (the scheme, every
method's held-out error, the choice) and, when there is something to say, ``warnings`` (:func:`guard_warnings`:
too few samples, samples spanning too narrow a range, auto's choice predicting its held-out samples badly or
judged on one fold, fitted parameters at their bounds, values impossibly far below zero). The method's own
``residuals`` are on the samples it was built from: they
are reported as such and never used to choose a method.
"""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.atomic import atomic_open
from reconstruction.base import Reconstruction
from reconstruction.core import merlgrid, merltable
from reconstruction.core.geometry import inplane_to_dirs
from reconstruction.core.metrics import relative_rmse_cos_dirs
from reconstruction.core.slicedata import Slice, describe_below_zero

Array = NDArray[np.float64]

__all__ = ["sample_residuals", "coverage", "build_report", "write_json", "guard_warnings", "NARROW_SPAN_DEG",
           "LARGE_HELD_OUT", "FEW_SAMPLES", "AT_BOUND", "parameters_at_bounds"]

#: samples whose widest outgoing range at any incidence is narrower than this (deg) leave almost the whole table
#: to extrapolation: said (a bench's one slice spans 160 deg; radians read as degrees span about 3)
NARROW_SPAN_DEG = 20.0
#: auto's choice predicting the samples it did not see worse than this (relative RMSE of f cos cos) is said: the
#: table is a guess from these samples (the demo's choice predicts to 1.3 %; the radians of issue 41 to 79 %)
LARGE_HELD_OUT = 0.3
#: fewer samples than this cannot support a full table whatever the method (issue 49: 3 samples forced through fit,
#: revolve and bivariate wrote tables 70-168 % off the demo's with no word): said
FEW_SAMPLES = 10
#: a fitted parameter within this relative distance (in log space) of its bound is "at its bound": said
AT_BOUND = 0.01

def _json_safe(x: Any) -> Any:
    """Recursively turn numpy values into plain Python and non-finite floats into None (strict JSON)."""
    if isinstance(x, dict):
        return {str(k): _json_safe(v) for k, v in x.items()}
    if isinstance(x, (list, tuple)):
        return [_json_safe(v) for v in x]
    if isinstance(x, np.ndarray):
        return _json_safe(x.tolist())
    if isinstance(x, (np.bool_, bool)):
        return bool(x)
    if isinstance(x, (np.integer,)):
        return int(x)
    if isinstance(x, (float, np.floating)):
        v = float(x)
        return v if np.isfinite(v) else None
    return x


def sample_residuals(rec: Reconstruction, s: Slice, table: ArrayLike | None = None) -> dict[str, Any]:
    """How the reconstruction (and the written table, if given) reproduce the samples ``s`` (f_r, 1/sr)."""
    f, _ = s.brdf()
    wi, wo = inplane_to_dirs(np.radians(s.theta_i_deg), np.radians(s.theta_o_deg))
    model = np.asarray(rec.eval(wi, wo), dtype=np.float64).reshape(len(s), -1)
    if model.shape[1] != f.shape[1]:
        model = np.broadcast_to(model, f.shape)
    r = model - f
    out: dict[str, Any] = {
        "samples": len(s),
        "rms_1_per_sr": float(np.sqrt(np.mean(r * r))),
        "max_abs_1_per_sr": float(np.max(np.abs(r))),
        "relative_rmse_cos": relative_rmse_cos_dirs(model, f, wi, wo),
    }
    if table is not None:
        tv = merltable.lookup(table, wi, wo, interpolate=True)
        tv = tv[:, :1] if f.shape[1] == 1 else tv
        out["table_relative_rmse_cos"] = relative_rmse_cos_dirs(tv, f, wi, wo)
    return out


def coverage(s: Slice, dropped_blind_spot: int = 0) -> dict[str, Any]:
    """What the samples cover: per incidence, the outgoing range and largest gap; the (theta_h, theta_d) bins hit."""
    out: dict[str, Any] = {"samples": len(s), "missing_blind_spot_rows": dropped_blind_spot, "incidences": []}
    for ti in s.incidences():  # one entry per incidence (a handful)
        to = np.sort(s.theta_o_deg[s.theta_i_deg == ti])
        out["incidences"].append({"theta_i_deg": float(ti), "samples": int(to.size),
                                  "theta_o_min_deg": float(to[0]), "theta_o_max_deg": float(to[-1]),
                                  "largest_gap_deg": float(np.max(np.diff(to))) if to.size > 1 else None})
    th = np.radians(np.abs(s.theta_o_deg - s.theta_i_deg) / 2)
    td = np.radians(np.abs(s.theta_o_deg + s.theta_i_deg) / 2)
    hit = np.zeros((merlgrid.N_TH, merlgrid.N_TD), dtype=bool)
    hit[merlgrid.theta_h_index(th), merlgrid.theta_d_index(td)] = True
    out["half_diff_bins_with_samples"] = int(hit.sum())
    out["half_diff_bins_total"] = merlgrid.N_TH * merlgrid.N_TD
    low = describe_below_zero(s)
    if low is not None:  # values impossibly far below zero for their uncertainty (NEGATIVE_SIGMAS): named
        out["below_zero"] = low
    return out


def parameters_at_bounds(params: Any) -> list[str]:
    """The fitted parameters (the report's ``parameters``: a list of lobes) lying at a bound of the fit
    (:data:`AT_BOUND`): alpha at 0.005 or 1.5, an index of refraction or an exponent at its limit; e.g.
    ``["ggx alpha 1.5 (its upper bound)"]``."""
    from reconstruction.methods.fit.model import ALPHA_MAX, ALPHA_MIN, EXP_MAX, EXP_MIN, IOR_MAX, IOR_MIN

    bounds = {"alpha": (ALPHA_MIN, ALPHA_MAX), "ior": (IOR_MIN, IOR_MAX), "exponent": (EXP_MIN, EXP_MAX)}
    out = []
    for lobe in params if isinstance(params, list) else []:
        if not isinstance(lobe, dict):
            continue
        for key, (lo, hi) in bounds.items():
            v = lobe.get(key)
            if not isinstance(v, (int, float)) or isinstance(v, bool) or not v > 0:
                continue
            near = abs(np.log(v / lo)) <= AT_BOUND * abs(np.log(hi / lo)), abs(np.log(hi / v)) <= AT_BOUND * abs(
                np.log(hi / lo))
            if near[0] or near[1]:
                out.append(f"{lobe.get('type', 'lobe')} {key} {v:.4g} (its {'lower' if near[0] else 'upper'} bound)")
    return out


def guard_warnings(cov: dict[str, Any], cv: dict[str, Any] | None, source: str, method: str | None = None,
                   params: Any = None) -> list[str]:
    """The run's warnings about what its samples can support, from the report's ``coverage`` and
    ``cross_validation`` (None without auto) and ``parameters``: fewer samples than :data:`FEW_SAMPLES`, a narrow
    outgoing range (:data:`NARROW_SPAN_DEG`), a chosen method whose held-out error exceeds :data:`LARGE_HELD_OUT`
    or rests on a single held-out fold, fitted parameters at their bounds (:func:`parameters_at_bounds`), values
    impossibly far below zero for their uncertainty (``coverage.below_zero``). ``source``: the inputs, ``method``
    the method that wrote the table, for the messages."""
    out = []
    n = cov.get("samples")
    what = f"{method}'s table" if method else "the table"
    if isinstance(n, int) and n < FEW_SAMPLES:
        out.append(f"{source}: only {n} sample(s) at {len(cov.get('incidences', []))} incidence(s): too few to support "
                   f"{what} (fewer than {FEW_SAMPLES}); it is extrapolated from them almost everywhere and can be far "
                   f"off{'' if cv else ' (a forced --method is not checked on held-out samples)'}; measure a wider "
                   "slice")
    if cov.get("below_zero"):
        out.append(f"{source}: {cov['below_zero']}: a dark, sign or unit error? these samples are impossible as "
                   "measured")
    bound = parameters_at_bounds(params)
    if bound:
        out.append(f"{source}: fitted parameter(s) at their bounds: {', '.join(bound)}: the samples do not "
                   f"determine them, so {what} rests on the bound, not on the data")
    spans = [float(c["theta_o_max_deg"]) - float(c["theta_o_min_deg"]) for c in cov.get("incidences", [])]
    if spans and max(spans) < NARROW_SPAN_DEG:
        out.append(f"{source}: the samples span only {max(spans):.3g} deg of theta_o (at most, over "
                   f"{len(spans)} incidence(s)) and fill {cov.get('half_diff_bins_with_samples')} of the "
                   f"{cov.get('half_diff_bins_total')} (theta_h, theta_d) bins: the table is extrapolated almost "
                   "everywhere; measure a wider range of outgoing angles")
    if cv:
        best = next((c for c in cv.get("scores", []) if c.get("label") == cv.get("chosen_label")), None)
        err = best.get("held_out_relative_rmse_cos") if best else None
        if best is not None and isinstance(cv.get("folds"), int) and cv["folds"] < 2:
            out.append(f"{source}: the chosen method, {cv.get('chosen_label')}, was judged on {cv['folds']} held-out "
                       "fold only: too few samples to tell how well it predicts the ones it did not see")
        if err is not None and err > LARGE_HELD_OUT:
            out.append(f"{source}: the chosen method, {cv.get('chosen_label')}, predicts the samples it did not "
                       f"see to {err:.0%} relative RMSE of f cos cos (above {LARGE_HELD_OUT:.0%}): the table is a "
                       "guess from these samples; measure more incidences or check the input's units and columns")
    return out


def build_report(*, rec: Reconstruction, choice: dict[str, Any], working: Slice, table: ArrayLike,
                 checks: dict[str, Any], inputs: dict[str, Any], colour: dict[str, Any], table_info: dict[str, Any],
                 outputs: dict[str, Any], timings: dict[str, float], dropped_blind_spot: int = 0) -> dict[str, Any]:
    """Assemble the JSON report (keys in the module docstring)."""
    details = rec.report()
    params = details.get("parameters", {})
    own = details.get("residuals") if isinstance(details.get("residuals"), dict) else {}
    # the method's own figures win (a fit to a scene's subset is judged on that subset); the rest is added
    residuals = {**sample_residuals(rec, working, table), **own,
                 "note": "on the samples the method was built from: how well it reproduces them, not how well it "
                         "predicts (an interpolating method reproduces its samples exactly); see cross_validation"}
    rep = {
        "method": rec.method,
        "method_requested": choice.get("requested", rec.method),
        "method_reason": choice.get("reason", ""),
        "parameters": params,
        "residuals": residuals,
        "coverage": coverage(working, dropped_blind_spot),
        "checks": checks,
        "inputs": inputs,
        "colour": colour,
        "table": table_info,
        "outputs": outputs,
        "timings_s": {k: round(v, 4) for k, v in timings.items()},
        "details": {k: v for k, v in details.items() if k not in ("parameters", "residuals", "method")},
    }
    if getattr(rec, "samples_left_out", None) is not None:  # what the method used of the input and left out, why
        rep["samples_left_out"] = rec.samples_left_out  # type: ignore[attr-defined]
    if "cross_validation" in choice:
        rep["cross_validation"] = choice["cross_validation"]
    return _json_safe(rep)


_SCALAR = r"(?:-?[0-9][0-9eE.+-]*|null|true|false)"
_FLAT_LIST = re.compile(rf"\[\s+({_SCALAR}(?:,\s+{_SCALAR})*)\s+\]")  # a list of numbers (no strings)


def dumps_compact(report: dict[str, Any]) -> str:
    """Indented, strict JSON in which every list of numbers (residuals, albedos, angles) takes one line."""
    text = json.dumps(_json_safe(report), indent=2, allow_nan=False)
    return _FLAT_LIST.sub(lambda m: "[" + " ".join(m.group(1).split()) + "]", text) + "\n"


def write_json(path: str | Path, report: dict[str, Any]) -> None:
    """Write ``report`` as indented, strict JSON (lists of scalars on one line), atomically (temporary file,
    fsync, rename)."""
    path = Path(path)
    text = dumps_compact(report)
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write(text)
