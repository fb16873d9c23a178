"""Revolve beyond its last measured incidence: a narrow forward lobe's divisor and its energy towards grazing.

A forward lobe is kept as its excess over the diffuse base times cos(theta_i) cos(theta_o) of the measurement, E(psi)
(nearly incidence-independent for a microfacet lobe: F D G G / 4), and evaluated as E / (cos theta_i cos theta_o).
The divisor is held at the smallest product measured, ``cmin``, so that no direction is amplified beyond what was
seen (for a broad lobe this stands in for the shadowing that takes its wings back towards the horizon). Beyond the
last measured incidence that hold reaches the mirror direction itself (cos^2 theta_i < cmin): the peak stops growing
while its solid angle keeps shrinking (d omega_o = 4 cos theta_d d omega_h), and a narrow lobe loses its energy: a
mirror captured at 20 / 40 / 60 deg kept 36 % of its albedo at 80 deg.

For a narrow lobe (half width at half maximum under :data:`NARROW_HWHM_DEG`: ggx alpha below about 0.035, whose
shadowing is under 4 % up to 85 deg), the hold is scaled with the incidence there, cmin (cos theta_i /
cos theta_last)^2 (:func:`floor_scale`): the lobe follows the 1 / cos^2 theta_i of its peak and keeps its albedo. The
excess is also capped (:func:`held_gains`) at the directional albedo it had at the last measured incidence (a
microfacet lobe without Fresnel keeps about that), so no direction gains energy that way. Broad lobes are unchanged.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from reconstruction.core.metrics import halfvector_albedo
from reconstruction.methods.revolve.thesis import Array

__all__ = ["NARROW_HWHM_DEG", "GAIN_NODES", "floor_scale", "held_gains", "hwhm_deg"]

#: A forward lobe narrower than this (half width at half maximum of its excess, deg of psi = 2 theta_h in the
#: plane of incidence; ggx: 1.29 alpha rad) follows its peak beyond the last measured incidence.
NARROW_HWHM_DEG = 2.5
#: Incidences (as a fraction of the way from the last measured one to 89.5 deg, denser towards grazing) at which the
#: cap of the forward excess is computed; it is interpolated linearly in theta_i in between.
GAIN_NODES = 1.0 - np.cos(np.linspace(0.0, np.pi / 2, 9))
_LAST_DEG = 89.5
# the albedo integrals over the half vector (geometric panels from 1e-5 rad): a plateau of a degree as a 60 deg lobe
_N_PANELS, _N_GAUSS, _N_PHI = 32, 4, 32


def hwhm_deg(values: Array, du: float) -> float:
    """Half width at half maximum (deg of psi) of a two-sided profile ``values`` (2 sides, G chord nodes of step
    ``du``, C channels; summed over channels), the wider side's; inf where it never falls to half."""
    lum = values.sum(axis=-1)
    peak = float(lum[:, 0].max())
    if not peak > 0:
        return math.inf
    widths = []
    for side in lum:  # two
        below = np.nonzero(side < 0.5 * peak)[0]
        widths.append(math.inf if below.size == 0 else math.degrees(2.0 * math.asin(min(1.0, below[0] * du / 2))))
    return max(widths)


def floor_scale(ci: Array, theta_last: float) -> Array:
    """The factor (<= 1) on the divisor's hold ``cmin`` at cos theta_i ``ci``: (ci / cos theta_last)^2 beyond the last
    measured incidence ``theta_last`` (radians), 1 before it."""
    c = math.cos(theta_last)
    return np.minimum((ci / c) ** 2, 1.0) if c > 0 else np.ones_like(ci)


def held_gains(eval_last: Callable[[Array, Array, float], Array], theta_last: float) -> tuple[Array, Array]:
    """(theta_i nodes in radians, gains <= 1) of the forward excess beyond ``theta_last``: at each node the factor
    that brings the excess's directional albedo (summed over channels) down to what it was at ``theta_last``, 1 where
    it is below. ``eval_last(wi, wo, gain)`` is the last measured incidence's model with the excess times ``gain``
    (:func:`floor_scale` applied), f_r (N, C)."""
    last = math.radians(_LAST_DEG)
    nodes = theta_last + (max(last, theta_last) - theta_last) * GAIN_NODES
    with_lobe = halfvector_albedo(lambda a, b: eval_last(a, b, 1.0), nodes, _N_PANELS, _N_GAUSS, _N_PHI).sum(axis=1)
    base = halfvector_albedo(lambda a, b: eval_last(a, b, 0.0), nodes, _N_PANELS, _N_GAUSS, _N_PHI).sum(axis=1)
    excess = with_lobe - base
    held = excess[0]
    gains = np.where(excess > held, held / np.maximum(excess, 1e-300), 1.0)
    return nodes, np.clip(gains, 0.0, 1.0)
