"""Which slice next: candidate incidences ranked by the errors to expect after measuring them.

For each candidate incidence theta_i (every :data:`STEP_DEG` the bench can reach: its light arm's limits, the
outgoing range and the blind spot of ``--bench``, else of the bench recorded in the slice file's metadata
(:func:`capture_limits`), defaults otherwise; never beyond the incidence where the beam overfills the sample,
which ``advice.excluded`` says) the slice a bench would measure there
(theta_o every 2 deg, the blind spot left out) is added to the reference posterior's design
(:func:`reconstruction.assess.uncertainty.reference_posterior`): the posterior covariance after a measurement
does not depend on the values measured, so sigma after that slice is known before it is measured. Each candidate's
expected PSNR and cosl2 (:func:`reconstruction.assess.uncertainty.expected_errors`, all candidates in one stacked
render) rank them; the bench time of each comes from the bench's time model (moves of 2 deg between points, the
settling and the readings of ``--bench``).

The model's ranking is finer than it can resolve: on the real materials the three best candidates' expected PSNR
differ by a median 0.09 dB, while the actual PSNR after a slice varies by several dB between neighbouring
incidences (benchmarks/bench_advice.py). So candidates within :data:`TIE_DB` of the best expected PSNR count as
equivalent, and among them the recommendation is the one nearest :data:`PREFERRED_DEG`, the best fixed second
incidence after a 40 deg slice on 24 real materials (median PSNR 37.14 dB against 35.82 dB for the model's own
first choice; on 23 others, 36.20 against 36.05 dB, the best fixed choice there 36.29 dB; the report's
``advice.tie`` says when this rule decided). With a budget the best set of further
slices whose total time fits is chosen greedily (each step adds the slice that gains the most expected PSNR per second).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.assess.uncertainty import expected_errors, expected_scene_errors
from reconstruction.base import ReconstructionError
from reconstruction.core.scene import RECONSTRUCTION_DEFAULT_RANGE_DEG, scene_pairs
from reconstruction.core.slicedata import Slice
from reconstruction.methods import prior as P

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

Array = NDArray[np.float64]

__all__ = ["BenchLimits", "bench_limits", "capture_limits", "candidate_slice", "join_slices", "advise", "recommend",
           "TIE_DB", "PREFERRED_DEG"]

STEP_DEG = 5.0
OUT_STEP_DEG = 2.0
#: candidates within this much expected PSNR (dB) of the best are equivalent within the model's resolution
TIE_DB = 0.5
#: among equivalent candidates, the one nearest this incidence (deg) is recommended: the best fixed second slice
#: after a 40 deg slice on 24 real materials (benchmarks/bench_advice.py --every 6 --step 5: 75 deg)
PREFERRED_DEG = 75.0


@dataclass(frozen=True)
class BenchLimits:
    """What a bench can measure and how long a point takes (defaults: the shipped simulated bench)."""

    light_min_deg: float = 0.0
    light_max_deg: float = 80.0
    detector_max_deg: float = 80.0
    blind_spot_deg: float = 4.0
    point_s: float = 0.05 + 4 * 0.01 + 0.04  # settling + repeats x integration + a 2 deg move
    source: str = "defaults (no --bench, and no bench recorded in the slice file)"
    #: the incidence (deg) beyond which the beam overfills the sample (None: never, or the diameters are unknown)
    overfills_beyond_deg: float | None = None
    footprint: str = ""  # the beam and sample diameters, for the message


def bench_limits(path: str | Path | None) -> BenchLimits:
    """The :class:`BenchLimits` of a bench file (``[axes.light]``/``[axes.detector]`` limits,
    ``[bench].blind_spot_half_width_deg``, ``[motion].settle_s``, ``[detector]`` integration and repeats,
    ``[motion].velocity_deg_s``); the defaults without one. Bad file: :class:`ReconstructionError`."""
    if path is None:
        return BenchLimits()
    p = Path(path)
    try:
        doc = tomllib.loads(p.read_text(encoding="utf-8"))
    except OSError as e:
        raise ReconstructionError(f"--bench {p}: cannot read ({e.strerror or e})") from None
    except tomllib.TOMLDecodeError as e:
        raise ReconstructionError(f"--bench {p}: invalid TOML: {e}") from None
    try:
        axes, motion, det = doc.get("axes", {}), doc.get("motion", {}), doc.get("detector", {})
        light, detector = axes.get("light", {}), axes.get("detector", {})
        speed = float(motion.get("velocity_deg_s", 60.0))
        point = (float(motion.get("settle_s", 0.05)) + int(det.get("repeats", 4))
                 * float(det.get("integration_time_s", 0.01)) + OUT_STEP_DEG / max(speed, 1e-3))
        bench = doc.get("bench", {})
        beam, sample = bench.get("beam_diameter_mm"), bench.get("sample_diameter_mm")
        return BenchLimits(light_min_deg=max(0.0, float(light.get("min_deg", 0.0))),
                           light_max_deg=min(85.0, float(light.get("max_deg", 80.0))),
                           detector_max_deg=min(85.0, float(max(abs(detector.get("min_deg", -80.0)),
                                                                abs(detector.get("max_deg", 80.0))))),
                           blind_spot_deg=float(doc.get("bench", {}).get("blind_spot_half_width_deg", 4.0)),
                           point_s=point, source=str(p), **_footprint(beam, sample))
    except (TypeError, ValueError, AttributeError) as e:
        raise ReconstructionError(f"--bench {p}: expected numbers in [axes.*], [motion], [detector] ({e})") from None


def _footprint(beam: Any, sample: Any) -> dict[str, Any]:
    """The :class:`BenchLimits` footprint fields of a beam and a sample diameter (mm; None when unknown)."""
    from reconstruction.schema.optics import footprint_limit_deg

    if not all(isinstance(x, (int, float)) and not isinstance(x, bool) and x > 0 for x in (beam, sample)):
        return {}
    return {"overfills_beyond_deg": footprint_limit_deg(float(beam), float(sample)),
            "footprint": f"a {float(beam):g} mm beam on a {float(sample):g} mm sample"}


def capture_limits(meta: dict[str, Any], where: str) -> BenchLimits | None:
    """The :class:`BenchLimits` of the bench recorded in a slice file's metadata (``meta``, docs/formats.md:
    ``config_settings`` and ``config_fingerprint`` hold the bench file's keys, ``instrument`` the beam and sample
    diameters), or None when it records none (a generic table, a file of another program). ``where``: the file,
    for the report."""
    cs, fp = meta.get("config_settings"), meta.get("config_fingerprint")
    if not isinstance(cs, dict) and not isinstance(fp, dict):
        return None
    keys = {**(fp if isinstance(fp, dict) else {}), **(cs if isinstance(cs, dict) else {})}

    def num(key: str, default: float) -> float:
        v = keys.get(key)
        return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) and np.isfinite(v) else default

    repeats = num("[plan].repeats", num("[detector].repeats", 4.0))
    point = (num("[motion].settle_s", 0.05) + repeats * num("[detector].integration_time_s", 0.01)
             + OUT_STEP_DEG / max(num("[motion].velocity_deg_s", 60.0), 1e-3))
    inst = meta.get("instrument") if isinstance(meta.get("instrument"), dict) else {}
    name = meta.get("bench_name") or meta.get("bench") or "unnamed"
    return BenchLimits(light_min_deg=max(0.0, num("[axes.light].min_deg", 0.0)),
                       light_max_deg=min(85.0, num("[axes.light].max_deg", 80.0)),
                       detector_max_deg=min(85.0, max(abs(num("[axes.detector].min_deg", -80.0)),
                                                      abs(num("[axes.detector].max_deg", 80.0)))),
                       blind_spot_deg=num("[bench].blind_spot_half_width_deg", 4.0), point_s=point,
                       source=f"the bench recorded in {where} ({name})",
                       **_footprint(inst.get("beam_diameter_mm", keys.get("[bench].beam_diameter_mm")),
                                    inst.get("sample_diameter_mm", keys.get("[bench].sample_diameter_mm"))))


def candidate_slice(theta_i_deg: float, limits: BenchLimits, channels: list[str]) -> Slice:
    """The in-plane slice a bench measures at ``theta_i_deg`` (values 0: only its geometry is used)."""
    m = min(limits.detector_max_deg, 80.0)
    to = np.arange(-m, m + 1e-9, OUT_STEP_DEG)
    to = to[np.abs(to + theta_i_deg) >= limits.blind_spot_deg]
    z = np.zeros((to.size, len(channels)))
    return Slice(np.full(to.size, theta_i_deg), to, z, list(channels), z.copy(), source="candidate")


def join_slices(a: Slice, b: Slice) -> Slice:
    """The samples of two slices together (their angles and values; the rest of a slice file is not kept)."""
    v = np.concatenate([a.values, b.values])
    return Slice(np.concatenate([a.theta_i_deg, b.theta_i_deg]), np.concatenate([a.theta_o_deg, b.theta_o_deg]), v,
                 list(a.channels), np.zeros_like(v), source=a.source)


def _sigma_after(ref: P.PriorReconstruction, extra: Slice, sigma_now: Array | None = None) -> Array:
    """sigma of ln f (C, n_cells) once the samples of ``extra`` are added: the reference posterior's, and, when the
    table's sigma now (``sigma_now``, C x n_cells) holds more than the posterior (a table from another method, whose
    disagreement with the posterior counts), that excess shrunk as the posterior's variance shrinks."""
    assert ref.posterior is not None
    mu, comps, sig, resvar = ref.posterior["basis"]
    idx0, w0 = ref.posterior["design"]
    idx1, w1, _ = P._design(extra)
    idx, w = np.concatenate([idx0, idx1]), np.concatenate([w0, w1])
    sb = np.einsum("nj,knj->nk", w, comps[:, idx])
    sy = P.mapped_sigma(P.posterior_covariance(sb, sig), comps, resvar, ref.posterior["misfit"])
    new = P.sigma_ln_of(sy, ref.values, ref.posterior["scale"]).astype(np.float64)
    if sigma_now is None or ref.sigma_ln is None:
        return new
    old = ref.sigma_ln.astype(np.float64)
    excess = np.maximum(sigma_now**2 - old**2, 0.0)
    return np.minimum(np.sqrt(new**2 + excess * np.minimum(new**2 / np.maximum(old**2, 1e-12), 1.0)),
                      P.SIGMA_LN_MAX)


def advise(s: Slice, ref: P.PriorReconstruction, limits: BenchLimits, budget_s: float | None = None,
           current: dict[str, Any] | None = None, sigma_now: Array | None = None,
           f_grid: Array | None = None, scene: Any = None) -> dict[str, Any]:
    """The report's ``advice``: ``candidates`` (each ``theta_i_deg``, ``expected_psnr_db``, ``expected_cosl2``,
    ``bench_time_s``), best first, and ``recommended_theta_i_deg``; with ``budget_s``, ``plan``: the incidences of
    the best further slices that fit in that many seconds of bench time. ``current``: the expected errors of the
    table as it is (the report's ``uncertainty``), shown beside the candidates; ``sigma_now``: the table's sigma
    on the reduced grid (:func:`reconstruction.assess.uncertainty.sigma_grid`); ``f_grid``: the table's f_r there
    (C, n_cells), whose images the expected errors are of (the reference posterior's without it). ``scene``
    (:class:`reconstruction.core.scene.Scene`): the candidates also carry ``expected_scene_psnr_db`` and
    ``expected_scene_linear_error`` (the scene's own images, :func:`scene_pairs`), are ranked by them, and a tie
    goes to the incidence nearest :data:`PREFERRED_DEG` within the scene's theta_i range."""
    f = ref.values if f_grid is None else f_grid
    lo = max(limits.light_min_deg, 0.0)
    hi = min(limits.light_max_deg, 80.0)
    thetas = [float(t) for t in np.arange(np.ceil(lo / STEP_DEG) * STEP_DEG, hi + 1e-9, STEP_DEG)]
    measured = set(np.round(np.unique(s.theta_i_deg), 6).tolist())
    thetas = [t for t in thetas if round(t, 6) not in measured]
    over = limits.overfills_beyond_deg
    excluded = [{"theta_i_deg": t, "why": f"the beam overfills the sample beyond {over:.1f} deg ({limits.footprint}):"
                 " part of the light misses the sample, and a correction of the lost light is a guess"}
                for t in thetas if over is not None and t > over + 1e-9]
    thetas = [t for t in thetas if over is None or t <= over + 1e-9]
    said = {"excluded": excluded} if excluded else {}
    if not thetas:  # a hemispherical file, or slices at every step: nothing to advise, said rather than refused
        return {"recommended_theta_i_deg": None, "candidates": [], "bench": limits.source, "current": current,
                **said, "note": (f"every incidence the bench can reach ({lo:g} to {hi:g} deg, every {STEP_DEG:g} "
                                 "deg) is measured already" if not excluded else
                                 "every incidence the bench can still reach is measured already or beyond where "
                                 "its beam overfills the sample (excluded)")}
    slices = [candidate_slice(t, limits, list(s.channels)) for t in thetas]
    sig = np.stack([_sigma_after(ref, c, sigma_now) for c in slices])
    exp = expected_errors(f, sig)
    pairs = scene_pairs(scene) if scene is not None else None
    if pairs is not None:
        for e, es in zip(exp, expected_scene_errors(f, sig, pairs), strict=True):
            e.update(es)
    cands = [{"theta_i_deg": t, "expected_psnr_db": round(e["expected_psnr_db"], 2),
              "expected_cosl2": round(e["expected_cosl2"], 4),
              "expected_linear_image_error": round(e["expected_linear_image_error"], 4),
              **({"expected_scene_psnr_db": round(e["expected_scene_psnr_db"], 2),
                  "expected_scene_linear_error": round(e["expected_scene_linear_error"], 4)} if scene else {}),
              "bench_time_s": round(len(c) * limits.point_s, 1)}
             for t, e, c in zip(thetas, exp, slices, strict=True)]
    key = "expected_scene_psnr_db" if scene is not None else "expected_psnr_db"
    cands.sort(key=lambda c: (-c[key], c["expected_cosl2"]))
    preferred = PREFERRED_DEG
    if scene is not None:
        lo_s, hi_s = scene.ranges(RECONSTRUCTION_DEFAULT_RANGE_DEG)[0]
        preferred = float(np.clip(PREFERRED_DEG, lo_s, hi_s))
    pick, tied = recommend({c["theta_i_deg"]: c[key] for c in cands}, preferred)
    out: dict[str, Any] = {"recommended_theta_i_deg": pick, "candidates": cands,
                           **({"tie": {"within_db": TIE_DB, "equivalent_theta_i_deg": sorted(tied),
                                       "rule": f"the model cannot separate these (expected PSNR within {TIE_DB:g} dB "
                                               f"of the best); the one nearest {preferred:g} deg, "
                                               + ("the best fixed second slice on the real materials"
                                                  if preferred == PREFERRED_DEG else
                                                  f"the nearest the scene's incidences come to {PREFERRED_DEG:g} "
                                                  "deg, the best fixed second slice on the real materials")}}
                              if len(tied) > 1 else {}),
                           "ranked_by": (f"expected PSNR in the scene's own images ({scene.name})" if scene is not None
                                         else "expected PSNR of a sphere under key and rim lighting"),
                           "bench": limits.source, "current": current, **said,
                           "method": "the reference posterior's sigma after each candidate slice (value-independent)"
                                     ", its expected PSNR (key and rim lighting) and cosl2"}
    if budget_s is not None:
        out["budget_s"] = budget_s
        now = (current or {}).get(key)
        out["plan"] = _plan(s, ref, limits, budget_s, thetas, float(now) if now is not None else 0.0, sigma_now, f,
                            pairs)
    return out


def recommend(expected_psnr_db: dict[float, float], preferred_deg: float = PREFERRED_DEG
              ) -> tuple[float, list[float]]:
    """(the recommended incidence, the incidences equivalent to the best) from each candidate's expected PSNR
    (deg -> dB): within :data:`TIE_DB` of the best, the one nearest ``preferred_deg`` (module docstring)."""
    best = max(expected_psnr_db.values())
    tied = sorted(t for t, v in expected_psnr_db.items() if v >= best - TIE_DB)
    return min(tied, key=lambda t: (abs(t - preferred_deg), -t)), tied


def _plan(s: Slice, ref: P.PriorReconstruction, limits: BenchLimits, budget_s: float, thetas: list[float],
          psnr_start: float, sigma_now: Array | None, f: Array, pairs: Any = None) -> dict[str, Any]:
    """Greedy: add the candidate with the largest expected PSNR gain per second until the budget is spent (the
    PSNR of the scene's own images with ``pairs``, :func:`scene_pairs`)."""
    chosen: list[float] = []
    spent = 0.0
    extra: Slice | None = None
    psnr_now = psnr_start
    left = list(thetas)
    while left:
        fits = [t for t in left
                if spent + len(candidate_slice(t, limits, list(s.channels))) * limits.point_s <= budget_s]
        if not fits:
            break
        tries = [candidate_slice(t, limits, list(s.channels)) for t in fits]
        sig = np.stack([_sigma_after(ref, tr if extra is None else join_slices(extra, tr), sigma_now) for tr in tries])
        exp = ([{"expected_psnr_db": e["expected_scene_psnr_db"]} for e in expected_scene_errors(f, sig, pairs)]
               if pairs is not None else expected_errors(f, sig))
        gains = [(e["expected_psnr_db"] - psnr_now) / (len(tr) * limits.point_s)
                 for e, tr in zip(exp, tries, strict=True)]
        k = int(np.argmax(gains))
        if chosen and exp[k]["expected_psnr_db"] <= psnr_now + 0.05:
            break  # nothing left gains anything
        chosen.append(fits[k])
        spent += len(tries[k]) * limits.point_s
        extra = tries[k] if extra is None else join_slices(extra, tries[k])
        psnr_now = exp[k]["expected_psnr_db"]
        left.remove(fits[k])
    return {"theta_i_deg": chosen, "bench_time_s": round(spent, 1), "expected_psnr_db": round(psnr_now, 2)}
