"""Conversion of detector readings to BRDF values (1/sr): pure math, no devices.

Signal model of an in-plane bench whose detector sees the whole illuminated spot (counts, dark subtracted)::

    S - S_dark = K * f_r(theta_i, theta_o) * cos(theta_o)

with K = source power x detector solid angle (absolute calibration gives K directly). A Lambertian white
reference of reflectance rho_ref measured at the reference geometry (theta_i_ref, theta_o_ref) gives
``S_ref - S_dark = K * rho_ref / pi * cos(theta_o_ref)``, hence the relative calibration::

    f_r = (S - S_dark) / (S_ref - S_dark) * rho_ref / pi * cos(theta_o_ref) / cos(theta_o)

(the cosine correction is 1 when the sample is measured at the reference geometry). A **ratio reading**
(``[detector].monitor``: a monitor photodiode sees the source itself, the board reports its sum beside every
reading) divides each net signal by the source's power at that moment: ``S - S_dark`` is multiplied by
``M_ref / M``, the monitor's rate (counts a second of integration) during the white reference over the one during
the reading, so that the source's drift and warm-up between the calibration and the point divide out.

Where the illuminated spot overfills the sample (``footprint``: a beam of diameter D lights D / cos theta_i of a
sample of diameter d) only the fraction frac(theta_i) of the light reaches it
(:func:`reconstruction.schema.optics.footprint_fraction`); the reading is then divided by frac(theta_i) /
frac(theta_i_ref), where frac(theta_i) is at least the footprint's smallest correctable fraction (below it, the
sample is left uncorrected). The uncertainty kept per sample is the standard deviation of the mean of the repeats,
propagated through the same factor; the reference and dark uncertainties are common to the whole slice and are
stored in the metadata instead.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Reading", "Calibration", "reference_rho", "pool", "measure_gain_factors", "gain_factors_of",
           "GAIN_RATIO_TOLERANCE", "GAIN_RATIO_PRECISION", "drift_of"]

#: A measured gain ratio further than this from the nominal one is not believed (a reading gone wrong, not a 1 %
#: or 5 % resistor): the nominal ratio is kept, with a warning.
GAIN_RATIO_TOLERANCE = 0.2
#: A gain's ratio is measured only where the white reference's net signal there is known to this relative
#: standard uncertainty (a lower gain reads less of it).
GAIN_RATIO_PRECISION = 0.002

Array = NDArray[np.float64]


@dataclass(frozen=True)
class Reading:
    """A detector reading: ``mean`` and ``std`` (sample standard deviation over the repeats) per channel in raw
    counts, ``n`` repeats, ``saturated`` = how many repeats clipped; ``monitor``: the source monitor's rate during
    the reading (the board's ``monitor=`` sum over one repeat's integration time, divided by it: counts/s), None
    when the detector reports none."""

    mean: Array
    std: Array
    n: int
    saturated: int = 0
    monitor: float | None = None

    @property
    def std_of_mean(self) -> Array:
        return self.std / math.sqrt(max(self.n, 1))

    def to_meta(self) -> dict[str, Any]:
        return {"mean": [float(x) for x in self.mean], "std": [float(x) for x in self.std], "n": self.n,
                **({"monitor_per_s": self.monitor} if self.monitor is not None else {})}

    @classmethod
    def from_meta(cls, d: dict[str, Any]) -> Reading:
        mon = d.get("monitor_per_s")
        return cls(np.asarray(d["mean"], dtype=float), np.asarray(d["std"], dtype=float), int(d["n"]),
                   monitor=None if mon is None else float(mon))


def pool(a: Reading, b: Reading) -> Reading:
    """One reading of ``a.n + b.n`` repeats from two readings of the same quantity (mean and sample standard
    deviation pooled exactly; saturated repeats added; the monitor's rates weighted by repeats, when both have
    one)."""
    n = a.n + b.n
    mean = (a.n * a.mean + b.n * b.mean) / n
    ss = (a.n - 1) * a.std ** 2 + (b.n - 1) * b.std ** 2 + a.n * b.n / n * (a.mean - b.mean) ** 2
    mon = None if a.monitor is None or b.monitor is None else (a.n * a.monitor + b.n * b.monitor) / n
    return Reading(mean, np.sqrt(np.maximum(ss, 0.0) / max(n - 1, 1)), n, a.saturated + b.saturated, mon)


def reference_rho(reflectance: float | None, spectrum: tuple[Sequence[float], Sequence[float]] | None,
                  wavelengths_nm: ArrayLike | None, band_weights: ArrayLike | None = None) -> Array:
    """Reference reflectance per detector channel: the number; or the spectrum interpolated at the
    spectrometer's wavelengths (clamped at the ends); or, for a photodiode, the spectrum weighted by its band
    (``band_weights`` on :data:`reconstruction.schema.optics.BAND_NM`; without them the mean of its values)."""
    if spectrum is None:
        assert reflectance is not None
        n = 1 if wavelengths_nm is None else int(np.asarray(wavelengths_nm).size)
        return np.full(n, float(reflectance))
    wl, val = (np.asarray(x, dtype=float) for x in spectrum)
    if wavelengths_nm is None:
        if band_weights is not None:
            from reconstruction.schema.optics import BAND_NM

            return np.array([float(np.asarray(band_weights, dtype=float) @ np.interp(BAND_NM, wl, val))])
        return np.array([float(val.mean())])
    return np.interp(np.asarray(wavelengths_nm, dtype=float), wl, val)


@dataclass(frozen=True)
class Calibration:
    """Everything needed to turn readings into f_r.

    ``mode`` "relative": ``reference`` (a :class:`Reading` of the white reference at ``reference_theta_o_deg``)
    and ``rho_ref`` per channel. "absolute": ``k_counts`` = source power x detector solid angle (counts per 1/sr
    at the configured integration time and gain). ``dark`` is the dark reading (source off).
    """

    mode: str
    dark: Reading
    reference: Reading | None = None
    rho_ref: Array | None = None
    reference_theta_o_deg: float = 0.0
    k_counts: float | None = None
    footprint: tuple[float, float, float] | None = None  # (beam_diameter_mm, sample_diameter_mm, min fraction)
    reference_theta_i_deg: float = 0.0
    #: the amplifier's real gains over its nominal ones (by nominal gain), measured on the white reference
    #: (:func:`measure_gain_factors`); auto-ranging converts with them. None: the nominal gains
    gain_factors: dict[float, float] | None = None
    gain_factors_measured: tuple[float, ...] = ()
    #: ratio readings (``[detector].monitor``, relative mode): every net signal times the reference's monitor rate
    #: over the reading's (module doc)
    monitor: bool = False

    def footprint_factor(self, theta_i_deg: float | Array | None) -> Array | float:
        """The footprint correction at ``theta_i_deg``: frac(theta_i_ref) / frac(theta_i) (absolute: 1 /
        frac(theta_i)) where frac(theta_i) is correctable, else 1."""
        if self.footprint is None or theta_i_deg is None:
            return 1.0
        from reconstruction.schema.optics import footprint_fraction

        beam, sample, lo = self.footprint
        frac = footprint_fraction(theta_i_deg, beam, sample)
        ref = float(footprint_fraction(self.reference_theta_i_deg, beam, sample)) if self.mode == "relative" else 1.0
        return np.where(frac >= lo, ref / np.maximum(frac, 1e-12), 1.0)

    def scale(self, theta_o_deg: float | Array) -> Array:
        """Factor turning dark-subtracted counts into f_r at ``theta_o_deg``: (..., C)."""
        to = np.asarray(theta_o_deg, dtype=float)[..., None]
        cos_o = np.maximum(np.cos(np.radians(to)), 1e-6)
        if self.mode == "relative":
            assert self.reference is not None and self.rho_ref is not None
            net = self.reference.mean - self.dark.mean
            if np.any(net <= 0):
                raise ValueError("the white reference reads no more than the dark level: check the source and "
                                 "the reference geometry")
            cos_ref = math.cos(math.radians(self.reference_theta_o_deg))
            return self.rho_ref / math.pi * cos_ref / (net * cos_o)
        assert self.k_counts is not None
        return np.broadcast_to(1.0 / (self.k_counts * cos_o), to.shape[:-1] + self.dark.mean.shape)

    def brdf(self, reading: Reading, theta_o_deg: float, theta_i_deg: float | None = None) -> tuple[Array, Array]:
        """(f_r, std of the mean of f_r) per channel for a reading at ``theta_o_deg`` (footprint-corrected at
        ``theta_i_deg`` when given)."""
        k = self.scale(theta_o_deg) * self.footprint_factor(theta_i_deg) * self.monitor_factor(reading)
        f = (reading.mean - self.dark.mean) * k
        return f, reading.std_of_mean * np.abs(k)

    def monitor_factor(self, reading: Reading) -> float:
        """The ratio reading's factor for ``reading``: the white reference's monitor rate over the reading's (1
        without :attr:`monitor`). Raises ValueError when either has no monitor rate above 0 (a board built without
        MONITOR=1, or no monitor photodiode on A1)."""
        if not self.monitor:
            return 1.0
        ref = self.reference.monitor if self.reference is not None else None
        for what, m in (("the white reference", ref), ("the reading", reading.monitor)):
            if m is None or not m > 0:
                raise ValueError(f"[detector].monitor = true, but {what} has "
                                 + ("no monitor= field (firmware built without MONITOR=1?)" if m is None else
                                    f"a monitor reading of {m:g} counts/s (no monitor photodiode on A1, or it sees "
                                    "no light from the source?)"))
        assert ref is not None and reading.monitor is not None
        return ref / reading.monitor

    def relative_uncertainty(self) -> Array:
        """Relative standard uncertainty common to all samples (reference and dark means), per channel."""
        if self.mode != "relative" or self.reference is None:
            return np.zeros_like(self.dark.mean)
        net = self.reference.mean - self.dark.mean
        var = self.reference.std_of_mean ** 2 + self.dark.std_of_mean ** 2
        return np.sqrt(var) / np.abs(net)

    def to_meta(self) -> dict[str, Any]:
        d: dict[str, Any] = {"dark": self.dark.to_meta()}
        if self.reference is not None:
            d["reference_reading"] = self.reference.to_meta()
        if self.rho_ref is not None:
            d["rho_ref"] = [float(x) for x in self.rho_ref]
        if self.k_counts is not None:
            d["k_counts"] = self.k_counts
        d["common_relative_uncertainty"] = [float(x) for x in self.relative_uncertainty()]
        if self.monitor:
            d["monitor_ratio"] = True
        if self.gain_factors is not None:
            d["gain_factors"] = {f"{g:g}": float(f) for g, f in sorted(self.gain_factors.items())}
            d["gain_factors_measured"] = [float(g) for g in self.gain_factors_measured]
        return d


def gain_factors_of(meta: dict[str, Any]) -> tuple[dict[float, float] | None, tuple[float, ...]]:
    """(gain_factors, gain_factors_measured) of a calibration's metadata (:meth:`Calibration.to_meta`)."""
    if "gain_factors" not in meta:
        return None, ()
    return ({float(g): float(f) for g, f in meta["gain_factors"].items()},
            tuple(float(g) for g in meta.get("gain_factors_measured", ())))


def drift_of(nets: Sequence[float]) -> float:
    """The relative spread of readings of one source (a warm-up check): (max - min) / mean of ``nets``."""
    v = np.asarray(nets, dtype=float)
    return float((v.max() - v.min()) / max(abs(float(v.mean())), 1e-300))


def measure_gain_factors(readings: dict[float, tuple[Reading, Reading]], anchor: float, saturation: float,
                         headroom: float = 0.8) -> tuple[dict[float, float], tuple[float, ...]]:
    """The amplifier's real gains relative to its nominal ones, from the white reference read at every gain
    (``readings``: nominal gain -> (reference reading, dark at that gain), raw counts at one integration time).

    The gain the reference was ranged to (``anchor``) is the reference: its factor is 1 (the white reference
    calibrates it). A gain below it whose reading is clean (no clipped repeat, mean + 3 std below ``headroom`` of
    ``saturation``) and whose net signal is known to :data:`GAIN_RATIO_PRECISION` gets the measured factor
    ``(net_g / net_anchor) * anchor / g``; a gain not measurable that way (above the anchor the reference
    saturates; far below it the signal is lost in the noise) keeps the factor of its measured neighbour towards the
    anchor, i.e. the nominal ratio to it. Returns ({nominal gain: factor}, the gains measured)."""
    gains = sorted(readings, reverse=True)
    ref, dark = readings[anchor]
    net_anchor = float(np.max(ref.mean - dark.mean))
    factors = {g: 1.0 for g in gains}
    measured: list[float] = []
    if net_anchor <= 0:
        return factors, ()
    last = 1.0
    for g in gains:
        if g >= anchor:
            continue
        rd, dk = readings[g]
        net = float(np.max(rd.mean - dk.mean))
        err = float(np.max(np.hypot(rd.std_of_mean, dk.std_of_mean)))
        clean = not rd.saturated and np.all(rd.mean + 3 * rd.std < headroom * saturation)
        if clean and net > 0 and err <= GAIN_RATIO_PRECISION * net:
            f = net / net_anchor * anchor / g
            if abs(f - 1.0) <= GAIN_RATIO_TOLERANCE:
                last = f
                measured.append(g)
        factors[g] = last
    return factors, tuple(measured)
