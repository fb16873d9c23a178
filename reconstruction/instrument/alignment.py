"""The bench's alignment from data: the arms' zero offsets, the sample's tilt in the plane and how far its surface
sits off the rotation axis, from specular peaks of a first-surface mirror and a sweep over the white reference
(docs/build-a-bench.md, Alignment). ``gonio-align`` (:mod:`acquisition.align`) measures; the simulator's
``[simulator.misalignment]`` uses :func:`true_angles` to be misaligned the same way.

Conventions (angles in degrees, lengths in mm). The arms report theta_i (light arm, positive on the -x side) and
theta_o (detector arm, positive on the +x side, the specular side). Physically the light arm stands at
``theta_i + a`` and the detector arm at ``theta_o + b`` from the reference axis (the normal of the holder's seat);
the sample's normal is tilted by ``t`` towards +x and its surface lies ``h`` above the axis (towards the arms).
The collimated beam is aimed at the axis; the detector looks at the axis from ``R`` (its aperture's distance).

Identifiability. A specular peak found at theta_o for theta_i says
``theta_o = theta_i + c + delta(theta_i)`` with ``c = a - b + 2 t`` and ``delta ~ -2 h sin(theta_i) / R``
(the reflected ray misses the axis by ``2 h sin theta_i``). Over several incidences the constant ``c`` and the
surface offset ``h`` (the part growing as sin theta_i) separate; ``a``, ``b`` and ``t`` do not: turning both arms by
the same angle (``a + e``, ``b + e``) keeps every specular peak where it was, and so does any ``t`` traded against
``a - b``. Two more measurements close it: the white reference (a diffuser, symmetric about its normal at normal
incidence) swept on both sides gives ``b`` (the detector arm's zero against the seat's normal, the reference lying
flat on the seat), and the mirror turned 180 deg about its normal (``t`` -> ``-t``) gives ``c' = a - b - 2 t``, so
``t = (c - c') / 4`` and ``a = (c + c') / 2 + b``. Without the turn, ``a + 2 t`` is known, not ``a`` and ``t``.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["AlignmentError", "true_angles", "specular_peak_deg", "peak_centre", "fit_specular", "fit_diffuse_zero",
           "Alignment", "SpecularFit", "combine", "zero_offset_for"]

Array = NDArray[np.float64]


class AlignmentError(ValueError):
    """The data do not determine the alignment (a peak outside the sweep, a fit that does not hold); the message
    says what and what to do."""


def true_angles(theta_i_deg: ArrayLike, theta_o_deg: ArrayLike, light_zero_deg: float = 0.0,
                detector_zero_deg: float = 0.0, tilt_deg: float = 0.0, surface_offset_mm: float = 0.0,
                detector_distance_mm: float = 70.0) -> tuple[Array, Array]:
    """The true (theta_i, theta_o) in degrees against the sample's normal for the arms' readings (any broadcast
    shapes): the light's direction, and the direction from where the beam's centre hits the surface to the
    detector's aperture. With no offset, tilt or surface offset they are the readings."""
    ti, to = np.broadcast_arrays(np.asarray(theta_i_deg, float), np.asarray(theta_o_deg, float))
    pl = np.radians(ti + light_zero_deg)
    pd = np.radians(to + detector_zero_deg)
    t = math.radians(tilt_deg)
    nx, nz = math.sin(t), math.cos(t)
    sx, sz = -np.sin(pl), np.cos(pl)                           # towards the source
    ns = np.maximum(nx * sx + nz * sz, 1e-9)
    qx, qz = sx * surface_offset_mm / ns, sz * surface_offset_mm / ns   # where the beam's centre meets the surface
    vx, vz = detector_distance_mm * np.sin(pd) - qx, detector_distance_mm * np.cos(pd) - qz

    def from_normal(x: Array, z: Array) -> Array:  # signed angle from the normal, positive towards +x
        return np.degrees(np.arctan2(x * nz - z * nx, x * nx + z * nz))

    return -from_normal(sx, sz), from_normal(vx, vz)


def specular_peak_deg(theta_i_deg: ArrayLike, c_deg: float, surface_offset_mm: float, detector_distance_mm: float,
                      alpha_deg: float = 0.0) -> Array:
    """Where the detector arm reads the specular peak for the light arm at ``theta_i_deg``: ``theta_i + c +
    delta``, ``delta`` from the ray reflected ``surface_offset_mm`` above the axis meeting the detector's circle
    (``alpha_deg``, the light arm's offset against the normal, moves delta a little)."""
    th = np.radians(np.asarray(theta_i_deg, float) + alpha_deg)
    h, r = surface_offset_mm, detector_distance_mm
    qx, qz = -h * np.tan(th), np.full_like(th, h)
    rx, rz = np.sin(th), np.cos(th)
    qr = qx * rx + qz * rz
    u = -qr + np.sqrt(np.maximum(qr * qr - (qx * qx + qz * qz) + r * r, 0.0))
    phi = np.degrees(np.arctan2(qx + u * rx, qz + u * rz))
    return np.asarray(theta_i_deg, float) + c_deg + (phi - np.degrees(th))


def peak_centre(theta_o_deg: ArrayLike, signal: ArrayLike, where: str = "") -> float:
    """The centre (degrees) of one peak sampled at ``theta_o_deg``: the mean of its two half-maximum crossings
    (linear interpolation), for the flat-topped response of a mirror seen through the detector's cone. Raises
    :class:`AlignmentError` when the peak is not inside the samples on both sides, or there is no peak."""
    x = np.asarray(theta_o_deg, float)
    y = np.asarray(signal, float)
    order = np.argsort(x)
    x, y = x[order], y[order]
    base = float(np.median(np.concatenate([y[:3], y[-3:]]))) if y.size >= 6 else float(y.min())
    top = float(y.max())
    k = int(np.argmax(y))
    if not top > 0 or top - base <= 0.2 * abs(top):
        raise AlignmentError(f"{where}no specular peak in the sweep from {x[0]:.2f} to {x[-1]:.2f} deg (the largest "
                             f"reading {top:.4g} is not above the rest, {base:.4g})")
    half = base + 0.5 * (top - base)
    left = np.nonzero(y[:k] < half)[0]
    right = np.nonzero(y[k:] < half)[0]
    if left.size == 0 or right.size == 0:
        side = "lower" if left.size == 0 else "upper"
        raise AlignmentError(f"{where}the specular peak runs past the sweep's {side} end ({x[0]:.2f} .. {x[-1]:.2f} "
                             "deg): the misalignment is larger than the sweep; widen --window, or align the arms "
                             "and the sample by eye with the laser first")
    i = int(left[-1])
    j = k + int(right[0])
    xl = x[i] + (half - y[i]) * (x[i + 1] - x[i]) / (y[i + 1] - y[i])
    xr = x[j - 1] + (half - y[j - 1]) * (x[j] - x[j - 1]) / (y[j] - y[j - 1])
    return 0.5 * (float(xl) + float(xr))


@dataclass(frozen=True)
class SpecularFit:
    """``c`` (deg) and the surface offset ``h`` (mm) of specular peaks, with the fit's rms residual (deg)."""

    c_deg: float
    surface_offset_mm: float
    rms_deg: float
    n: int


#: A fit whose peaks stray more than this (rms, deg) from one ``c`` and one surface offset is not trusted.
MAX_RMS_DEG = 0.03


def fit_specular(theta_i_deg: ArrayLike, peak_deg: ArrayLike, detector_distance_mm: float,
                 alpha_deg: float = 0.0) -> SpecularFit:
    """Least-squares ``c`` and ``h`` from the peaks ``peak_deg`` found at incidences ``theta_i_deg`` (at least 3,
    spread over 20 deg or more). Raises :class:`AlignmentError` when they do not fit (rms above
    :data:`MAX_RMS_DEG`): the surface is curved or far off the axis, or an arm slips."""
    from scipy.optimize import least_squares

    ti = np.asarray(theta_i_deg, float)
    pk = np.asarray(peak_deg, float)
    if ti.size < 3 or np.ptp(ti) < 20.0:
        raise AlignmentError(f"the specular fit needs 3 incidences or more spread over 20 deg or more (to tell "
                             f"the surface offset from the zero offsets), got {ti.size} spread over "
                             f"{np.ptp(ti) if ti.size else 0.0:.1f} deg")

    def resid(p: Array) -> Array:
        return specular_peak_deg(ti, p[0], p[1], detector_distance_mm, alpha_deg) - pk

    sol = least_squares(resid, np.array([float(np.mean(pk - ti)), 0.0]), x_scale=np.array([0.1, 1.0]))
    rms = float(np.sqrt(np.mean(sol.fun ** 2)))
    c, h = float(sol.x[0]), float(sol.x[1])
    if rms > MAX_RMS_DEG:
        raise AlignmentError(f"the specular peaks do not follow one zero offset and one surface offset: rms "
                             f"{rms:.3f} deg over {ti.size} incidences (at most {MAX_RMS_DEG} expected; c = "
                             f"{c:+.3f} deg, surface {h:+.2f} mm off the axis): the misalignment is beyond what "
                             "this fit models (a curved or loose sample, a surface far off the axis, an arm that "
                             "slips); bring the surface onto the axis with the holder's shims and align again")
    return SpecularFit(c, h, rms, int(ti.size))


def fit_diffuse_zero(theta_o_deg: ArrayLike, signal: ArrayLike) -> tuple[float, float]:
    """The detector arm's zero offset ``b`` (deg) from a diffuser at normal incidence swept over both sides of
    its normal: readings ``K cos(u) (1 + e u^2)`` with ``u = theta_o + b`` (a Lambertian cosine, with an even term
    for a real diffuser's departure from it), least squares; returns (b, rms of the relative residuals)."""
    from scipy.optimize import least_squares

    to = np.radians(np.asarray(theta_o_deg, float))
    y = np.asarray(signal, float)
    if (to > 0).sum() < 3 or (to < 0).sum() < 3:
        raise AlignmentError("the white reference sweep needs 3 readings or more on each side of the normal")
    scale = float(np.max(y))

    def resid(p: Array) -> Array:
        u = to + p[1]
        return (p[0] * np.cos(u) * (1.0 + p[2] * u * u) - y / scale)

    sol = least_squares(resid, np.array([1.0, 0.0, 0.0]))
    rel = sol.fun / np.maximum(y / scale, 1e-12)
    return float(np.degrees(sol.x[1])), float(np.sqrt(np.mean(rel ** 2)))


@dataclass(frozen=True)
class Alignment:
    """The fitted alignment: ``light_zero_deg`` (a) and ``detector_zero_deg`` (b), how far each arm stands past
    its reading; ``tilt_deg`` (t); ``surface_offset_mm`` (h); None for what the measurements did not determine
    (``light_plus_2tilt_deg`` = a + 2 t is then given)."""

    c_deg: float
    surface_offset_mm: float
    detector_zero_deg: float | None
    light_zero_deg: float | None
    tilt_deg: float | None
    light_plus_2tilt_deg: float | None
    rms_deg: float


def combine(first: SpecularFit, detector_zero_deg: float | None = None,
            turned: SpecularFit | None = None) -> Alignment:
    """What the measurements determine together (module docstring): ``first`` alone gives c and h; with the white
    reference's ``detector_zero_deg`` also b and a + 2 t; with the mirror ``turned`` 180 deg also t and a."""
    b = detector_zero_deg
    a = t = None
    a2t = first.c_deg + b if b is not None else None
    if turned is not None:
        t = (first.c_deg - turned.c_deg) / 4.0
        if b is not None:
            a = 0.5 * (first.c_deg + turned.c_deg) + b
    rms = first.rms_deg if turned is None else max(first.rms_deg, turned.rms_deg)
    h = first.surface_offset_mm if turned is None else 0.5 * (first.surface_offset_mm + turned.surface_offset_mm)
    return Alignment(first.c_deg, h, b, a, t, a2t, rms)


def zero_offset_for(zero_offset: float, direction: int, units_per_deg: float, arm_zero_deg: float) -> float:
    """The ``[axes.*].zero_offset`` that corrects an arm standing ``arm_zero_deg`` past its readings (controller
    units = zero_offset + direction x units_per_deg x degrees)."""
    return zero_offset - direction * units_per_deg * arm_zero_deg
