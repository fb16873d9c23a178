"""The bench's optics as a capture records and checks them: the instrument of the slice metadata (``instrument``,
:class:`reconstruction.instrument.response.Instrument`), the photodiode's band, and the footprint (the illuminated spot,
growing as 1 / cos theta_i, overfilling the sample at grazing incidence: the plan check warns, the calibration
corrects). Angles in degrees, lengths in mm.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from acquisition.config import BenchConfig
from reconstruction.instrument.response import Instrument
from reconstruction.schema.optics import band_name, footprint_fraction, footprint_limit_deg

__all__ = ["instrument_of", "band_of", "footprint_losses", "footprint_warning", "footprint_meta",
           "MIN_CORRECTABLE_FRACTION"]

#: Below this fraction of the beam on the sample the calibration does not correct (the spot's edge, the beam's
#: profile and the sample's centring dominate the reading): the samples are kept uncorrected and the metadata says so.
MIN_CORRECTABLE_FRACTION = 0.25


def band_of(cfg: BenchConfig) -> str:
    """What the value channels are: "silicon x halogen-3000K" (a photodiode's band) or "spectral"."""
    if cfg.detector.type in ("spectrometer", "seabreeze"):
        return "spectral"
    return band_name(cfg.detector.responsivity, cfg.bench.source_spectrum)


def instrument_of(cfg: BenchConfig) -> Instrument:
    """The bench's :class:`~reconstruction.instrument.response.Instrument` (detector cone, source divergence, beam and
    sample diameters, band)."""
    b = cfg.bench
    return Instrument(cfg.detector.acceptance_sr, b.source_divergence_deg, b.beam_diameter_mm, b.sample_diameter_mm,
                      band_of(cfg))


def footprint_losses(cfg: BenchConfig, theta_i_deg: Sequence[float]) -> list[tuple[float, float]]:
    """(theta_i, fraction of the beam on the sample) for the incidences whose spot overfills the sample."""
    b = cfg.bench
    ti = np.unique(np.abs(np.asarray(list(theta_i_deg), dtype=float)))
    frac = footprint_fraction(ti, b.beam_diameter_mm, b.sample_diameter_mm)
    return [(float(t), float(f)) for t, f in zip(ti, frac, strict=True) if f < 1.0 - 1e-9]


def footprint_warning(cfg: BenchConfig, theta_i_deg: Sequence[float]) -> str | None:
    """One line naming the incidences where the spot overfills the sample, the light lost and whether the
    calibration corrects it; None when none does."""
    lost = footprint_losses(cfg, theta_i_deg)
    if not lost:
        return None
    b = cfg.bench
    lim = footprint_limit_deg(b.beam_diameter_mm, b.sample_diameter_mm)
    parts = ", ".join(f"{t:g} deg ({100 * (1 - f):.0f} % lost"
                      f"{'' if f >= MIN_CORRECTABLE_FRACTION else ', not corrected'})" for t, f in lost)
    return (f"footprint: the {b.beam_diameter_mm:g} mm beam overfills the {b.sample_diameter_mm:g} mm sample beyond "
            f"theta_i = {lim:.1f} deg (beam / cos theta_i > sample): incidence(s) {parts}; the calibration "
            f"corrects for the light lost where at least {100 * MIN_CORRECTABLE_FRACTION:.0f} % of the beam "
            "falls on the sample ([bench].beam_diameter_mm, sample_diameter_mm)")


def footprint_meta(cfg: BenchConfig, theta_i_deg: Sequence[float]) -> dict[str, Any] | None:
    """The calibration metadata's ``footprint``: the diameters, the fraction per affected incidence, and which were
    corrected (None without diameters)."""
    b = cfg.bench
    if b.beam_diameter_mm is None or b.sample_diameter_mm is None:
        return None
    lost = footprint_losses(cfg, theta_i_deg)
    return {"beam_diameter_mm": b.beam_diameter_mm, "sample_diameter_mm": b.sample_diameter_mm,
            "overfills_beyond_theta_i_deg": footprint_limit_deg(b.beam_diameter_mm, b.sample_diameter_mm),
            "fraction_on_sample": {f"{t:g}": f for t, f in lost},
            "corrected_theta_i_deg": [t for t, f in lost if f >= MIN_CORRECTABLE_FRACTION],
            "uncorrected_theta_i_deg": [t for t, f in lost if f < MIN_CORRECTABLE_FRACTION],
            "min_correctable_fraction": MIN_CORRECTABLE_FRACTION}
