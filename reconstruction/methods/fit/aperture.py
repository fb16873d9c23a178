"""The fit with the instrument's angular response: microfacet columns averaged over the detector cone.

A sample's reading is the model averaged over the instrument's cone (:mod:`reconstruction.instrument.response`), not the
model at the cone's centre. The fit's columns (one lobe of unit amplitude) are linear in the amplitudes, so each
microfacet column is replaced by its cone average where that differs from the point value: at the samples near
the lobe's mirror direction (within :data:`NEAR_CONES` cone half angles, or 3 deg). The averages of a unit lobe
(no Fresnel factor) are tabulated once per distribution over log alpha (:data:`N_ALPHA` nodes from
:data:`ALPHA_FLOOR` to 1.5) and interpolated monotonically (PCHIP in log-log), so a fit costs about as much as
with point values; a Schlick factor is applied at the cone's centre (it varies little over a cone).

A lobe narrower than the aperture is recovered as far as the data allow. The report profiles chi^2 over alpha
(a 2-sigma range: chi^2 within :data:`PROFILE_DELTA_CHI2` of its minimum). When that range reaches
:data:`ALPHA_FLOOR` (the data cannot tell the lobe from a narrower one), or when even its widest alpha gives a lobe
whose half width in theta_o is under :data:`RESOLUTION_FRACTION` of the cone's half angle (the reading's shape is
then the cone's, and alpha shows only in the lobe's far tails, which a real surface's haze can mimic), the report
gives an upper bound: "below the instrument's angular resolution, alpha < X" with X the larger of the range's end
and :func:`resolution_alpha`, and the lobe's energy (its amplitude) as fitted.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np
from numpy.typing import NDArray

from reconstruction.core.models import Material, schlick
from reconstruction.core.slicedata import Slice
from reconstruction.instrument.response import Instrument, instrument_average_dirs, unit_lobe_tables

Array = NDArray[np.float64]

__all__ = ["Blur", "ALPHA_FLOOR", "resolution_alpha", "prefetch_tables"]

#: the smallest alpha a fit with a finite aperture may use (a lobe far narrower than any cone)
ALPHA_FLOOR = 1e-4
#: alpha nodes of the tabulated cone averages (log-spaced from ALPHA_FLOOR to 1.5)
N_ALPHA = 20
#: the distributions whose cone averages are tabulated together (the model search tries both)
TABLE_KINDS = ("ggx", "beckmann")
#: samples within this many cone half angles (or 3 deg) of the mirror direction use cone averages
NEAR_CONES = 15.0
#: a lobe whose half width (in theta_o) is under this fraction of the cone's half angle is below the resolution
RESOLUTION_FRACTION = 0.25
HWHM_PER_ALPHA = math.sqrt(math.sqrt(2.0) - 1.0)  # GGX: tan(theta_h at half maximum) = 0.64 alpha
#: the chi^2 rise (about 2 sigma) that bounds alpha in the report's profile
PROFILE_DELTA_CHI2 = 4.0


class Blur:
    """Cone-averaged unit microfacet columns for the samples of a fit (a view on a shared table)."""

    def __init__(self, instrument: Instrument, wi: Array, wo: Array, *, _root: Blur | None = None,
                 _rows: NDArray[np.int64] | None = None) -> None:
        self.instrument = instrument
        self.wi, self.wo = wi, wo
        self._root = _root if _root is not None else self
        if _root is None:
            a = math.radians(instrument.aperture_half_angle_deg) + math.radians(instrument.source_divergence_deg)
            mirror = wi * np.array([-1.0, -1.0, 1.0])
            ang = np.arccos(np.clip(np.sum(mirror * wo, axis=-1), -1.0, 1.0))
            self.near = np.nonzero(ang < max(NEAR_CONES * a, math.radians(3.0)))[0]
            self._tables: dict[str, Any] = {}  # PCHIP interpolators (scipy's, imported when first made)
            self.alphas = np.geomspace(ALPHA_FLOOR, 1.5, N_ALPHA)
            rows = np.arange(len(wi))
        else:
            assert _rows is not None
            rows = _rows
        self.rows = rows  # this view's samples as rows of the root
        # this view's samples that are near a mirror direction, and their columns in the root's table
        pos_in_root = np.full(len(self._root.wi), -1)
        pos_in_root[self._root.near] = np.arange(self._root.near.size)
        col = pos_in_root[rows]
        self.pos = np.nonzero(col >= 0)[0]
        self.cols = col[self.pos]
        h = wi[self.pos] + wo[self.pos]
        h = h / np.maximum(np.linalg.norm(h, axis=-1, keepdims=True), 1e-300)
        self.cos_d = np.sum(wi[self.pos] * h, axis=-1)

    def take(self, mask: NDArray[np.bool_]) -> Blur:
        """The view on the samples ``mask`` (N,) of this view."""
        return Blur(self.instrument, self.wi[mask], self.wo[mask], _root=self._root, _rows=self.rows[mask])

    def _table(self, kind: str) -> Any:
        from scipy.interpolate import PchipInterpolator

        root = self._root
        if kind not in root._tables:
            wi, wo = root.wi[root.near], root.wo[root.near]
            # N_ALPHA cone integrals of the near samples, once (shared with other fits inside shared_cone_averages),
            # both distributions in one pass (the model search tries both; the second costs about half the first)
            kinds = (kind,) + tuple(k for k in TABLE_KINDS if k != kind and k not in root._tables)
            tables = unit_lobe_tables(wi, wo, root.instrument, root.alphas, kinds)
            for k, vals in tables.items():
                root._tables[k] = PchipInterpolator(np.log(root.alphas), np.log(np.maximum(vals.T, 1e-300)), axis=0)
        return root._tables[kind]

    def column(self, kind: str, alpha: float, f0: float | None, point: Array) -> Array:
        """``point`` (N,), the unit lobe at the cones' centres, with the near samples' values cone-averaged."""
        if self.pos.size == 0:
            return point
        la = min(max(math.log(alpha), math.log(ALPHA_FLOOR)), math.log(1.5))
        avg = np.exp(self._table(kind)(la)[self.cols])
        out = np.array(point, dtype=np.float64, copy=True)
        out[self.pos] = avg * schlick(self.cos_d, f0)
        return out

    def reading(self, material: Material) -> Array:
        """The material as the instrument reads it at these samples (N, C): cone averages near the mirror
        directions, point values elsewhere."""
        out = material.eval(self.wi, self.wo)
        if self.pos.size:
            out[self.pos] = instrument_average_dirs(material, self.wi[self.pos], self.wo[self.pos], self.instrument)
        return out


def prefetch_tables(s: Slice) -> dict[Any, tuple[Array, Array]]:
    """fit's cone tables of the samples of ``s`` near a mirror direction (both distributions), computed as fit
    computes them, as entries of the shared cone averages
    (:func:`reconstruction.instrument.response.seed_shared_cone_averages`): what auto's forked child computes while
    the run imports scipy. Empty for a point instrument (or malformed metadata: fit reports it)."""
    from reconstruction.core.samples import sample_directions
    from reconstruction.instrument.response import InstrumentError, shared_cone_averages, shared_cone_entries

    try:
        inst = Instrument.from_meta(s.meta.get("instrument"))
    except InstrumentError:
        return {}
    if inst.detector_solid_angle_sr == 0.0 and inst.source_divergence_deg == 0.0:
        return {}
    wi, wo = sample_directions(s)
    with shared_cone_averages():
        b = Blur(inst, wi, wo)
        if b.near.size:
            unit_lobe_tables(wi[b.near], wo[b.near], inst, b.alphas, TABLE_KINDS)
        return shared_cone_entries()


def resolution_alpha(half_angle_deg: float) -> float:
    """The smallest alpha an instrument with this cone half angle (deg) resolves: a GGX lobe whose half width at
    half maximum in theta_o (2 atan(0.64 alpha)) is :data:`RESOLUTION_FRACTION` of the cone's half angle."""
    return math.tan(RESOLUTION_FRACTION * math.radians(half_angle_deg) / 2.0) / HWHM_PER_ALPHA
