"""revolve with the instrument: a specular peak narrower than the detector's cone held over the cone.

A reading at the mirror direction is the lobe's energy in the cone / (Omega cos theta_o). Where the peak is that
narrow (the mirror sample more than :data:`PLATEAU_RATIO` times its neighbours), the slice gets two samples at
the mirror reading on each side, at psi = 2 sqrt(Omega / (4 pi cos theta_i)) from the mirror direction (the cone's
solid angle in half-vector terms, as revolve's forward lobe measures psi = 2 theta_h), and two just beyond at the
tail's level (log-linear back-extrapolation of the next two samples beyond): the revolved lobe then holds the
energy the reading measured instead of a cone between samples 2 deg apart. Samples under the plateau (at grazing
incidence its half width may exceed the step) give way to it.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from reconstruction.base import ReconstructionError
from reconstruction.core.slicedata import Slice
from reconstruction.instrument.response import Instrument, InstrumentError

__all__ = ["hold_peaks_over_cone", "PLATEAU_RATIO"]

PLATEAU_RATIO = 4.0
_EDGE_DEG = 0.02  # the step down at the plateau's edge (deg of theta_o)


def hold_peaks_over_cone(s: Slice) -> tuple[Slice, list[dict[str, Any]]]:
    """``s`` (f_r) with plateau samples added where a peak is narrower than its instrument's cone, and what was
    done (one entry per incidence); ``s`` itself when there is no instrument or no such peak."""
    try:
        inst = Instrument.from_meta(s.meta.get("instrument"))
    except InstrumentError as e:
        raise ReconstructionError(f"{s.source}: metadata {e}") from None
    if inst.detector_solid_angle_sr <= 0:
        return s, []
    f, std = s.brdf()
    add_ti: list[float] = []
    add_to: list[float] = []
    add_v: list[np.ndarray] = []
    done: list[dict[str, Any]] = []
    drop = np.zeros(len(s), dtype=bool)  # samples under a plateau (a cone wider than the step, at grazing)
    for t in s.incidences():  # a handful of incidences
        at = np.nonzero(s.theta_i_deg == t)[0]
        order = at[np.argsort(s.theta_o_deg[at])]
        to, v = s.theta_o_deg[order], f[order]
        k = int(np.argmin(np.abs(to - t)))
        if abs(to[k] - t) > 1e-6 or k < 2 or k > to.size - 3:
            continue
        lum = v.sum(axis=1)
        if not lum[k] > PLATEAU_RATIO * max(float(lum[k - 1]), float(lum[k + 1]), 1e-300):
            continue
        r = math.degrees(2.0 * math.sqrt(inst.detector_solid_angle_sr
                                         / (4.0 * math.pi * max(math.cos(math.radians(t)), 1e-3))))
        new: list[tuple[float, np.ndarray]] = []
        inside = (np.abs(to - t) < r + 2 * _EDGE_DEG) & (np.arange(to.size) != k)  # under the plateau
        for side in (1, -1):
            beyond = np.nonzero(side * (to - t) >= r + 2 * _EDGE_DEG)[0]
            if beyond.size < 2:
                continue
            j1, j2 = (beyond[:2] if side > 0 else beyond[::-1][:2])
            a, b = v[j1], v[j2]
            d1, d2 = abs(to[j1] - t), abs(to[j2] - t)
            slope = np.where((a > 0) & (b > 0), np.log(np.maximum(a, 1e-300) / np.maximum(b, 1e-300)) / (d2 - d1),
                             0.0)
            edge = np.clip(a * np.exp(np.maximum(slope, 0.0) * (d1 - r - _EDGE_DEG)), np.minimum(a, v[k]), v[k])
            new += [(t + side * r, v[k]), (t + side * (r + _EDGE_DEG), edge)]
        if new:
            drop[order[inside]] = True
            for o, val in new:
                add_ti.append(float(t))
                add_to.append(o)
                add_v.append(val)
            done.append({"theta_i_deg": float(t), "plateau_half_width_deg": round(r, 6),
                         "peak_over_next": round(float(lum[k] / max(lum[k - 1], lum[k + 1], 1e-300)), 3),
                         "samples_under_plateau": int(inside.sum())})
    if not add_ti:
        return s, []
    vals = np.vstack(add_v)
    keep = ~drop
    assert s.repeats is not None and s.unix_time_s is not None
    out = Slice(np.r_[s.theta_i_deg[keep], add_ti], np.r_[s.theta_o_deg[keep], add_to], np.vstack([f[keep], vals]),
                list(s.channels), np.vstack([std[keep], np.zeros_like(vals)]),
                np.r_[s.repeats[keep], np.ones(len(add_ti), dtype=np.int64)],
                np.r_[s.unix_time_s[keep], np.zeros(len(add_ti))], meta={**s.meta, "quantity": "brdf"},
                source=s.source)
    return out.sorted(), done
