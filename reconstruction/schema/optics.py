"""The bench file's optics keys resolved to data, for both readers (``gonio-capture`` and ``gonio-sim``): the
photodiode's band (``[detector].responsivity`` x ``[bench].source_spectrum``) and the illuminated spot
(``[bench].beam_diameter_mm`` on ``sample_diameter_mm``).

Band: a photodiode's one channel is the responsivity-weighted reflectance
``rho_band = sum R(l) S(l) rho(l) / sum R(l) S(l)`` over :data:`BAND_NM` (380-780 nm, 5 nm: the visible range,
behind an IR-cut filter, where materials are defined), with R the detector's responsivity and S the source's
spectrum. Built in: ``"silicon"`` (a typical silicon photodiode, A/W), ``"halogen-3000K"`` (Planck's law at
3000 K) and ``"D65"`` (CIE, through colour-science); a CSV path gives ``wavelength_nm,value`` instead.

Footprint: a beam of diameter D at incidence theta_i lights an ellipse of semi-axes D / (2 cos theta_i) (in the
plane) and D / 2 on the sample; :func:`footprint_fraction` is the fraction of it that falls on a round sample
of diameter d (concentric, flat-top beam), exactly.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.schema.core import SchemaError

__all__ = ["BAND_NM", "SILICON_RESPONSIVITY", "spectrum_of", "band_weights", "band_name", "footprint_fraction",
           "footprint_limit_deg", "DEFAULT_BAND", "rgb_band_weights"]

#: The photodiode band of the simulated bench and of a bench file that names none (docs/instrument.md).
DEFAULT_BAND = ("silicon", "halogen-3000K")

#: Wavelengths (nm) of the photodiode band.
BAND_NM = np.arange(380.0, 780.0 + 1e-9, 5.0)
#: A typical silicon photodiode's responsivity (nm, A/W), e.g. of an FDS100-class PIN diode.
SILICON_RESPONSIVITY = (
    (350.0, 400.0, 450.0, 500.0, 550.0, 600.0, 650.0, 700.0, 750.0, 800.0, 850.0, 900.0, 950.0, 1000.0, 1100.0),
    (0.08, 0.12, 0.20, 0.27, 0.32, 0.37, 0.41, 0.45, 0.49, 0.53, 0.57, 0.60, 0.62, 0.55, 0.10))


def _planck(wl_nm: NDArray[np.float64], t_k: float) -> NDArray[np.float64]:
    """Relative spectral radiance of a black body at ``t_k`` kelvin (peak-normalised over ``wl_nm``)."""
    c2 = 1.4387769e7  # nm K
    x = wl_nm ** -5.0 / np.expm1(c2 / (wl_nm * t_k))
    return x / x.max()


def spectrum_of(name: str, kind: str, base_dir: Path | str = ".", where: str = "") -> NDArray[np.float64]:
    """The named or CSV spectrum on :data:`BAND_NM`: ``kind`` "responsivity" (``"silicon"``) or "source"
    (``"halogen-3000K"``, ``"halogen-<T>K"``, ``"D65"``). Raises :class:`SchemaError` naming ``where``."""
    if kind == "responsivity" and name == "silicon":
        return np.interp(BAND_NM, *SILICON_RESPONSIVITY)
    if kind == "source":
        if name.startswith("halogen-") and name.endswith("K"):
            try:
                t = float(name[len("halogen-"):-1])
            except ValueError:
                t = -1.0
            if 1000.0 <= t <= 10000.0:
                return _planck(BAND_NM, t)
        if name == "D65":
            from colour import SDS_ILLUMINANTS

            sd = SDS_ILLUMINANTS["D65"]
            return np.interp(BAND_NM, np.asarray(sd.wavelengths, float), np.asarray(sd.values, float))
    if not name.lower().endswith(".csv"):
        builtin = '"silicon"' if kind == "responsivity" else '"halogen-3000K" (or "halogen-<T>K"), "D65"'
        raise SchemaError(f"{where}: unknown {kind} {name!r}; expected {builtin} or a path to a "
                          "wavelength_nm,value CSV file")
    from reconstruction.schema.files import read_spectrum_csv

    p = Path(name)
    if not p.is_absolute():
        p = Path(base_dir) / p
    wl, val = read_spectrum_csv(p, where)
    out = np.interp(BAND_NM, np.asarray(wl, float), np.asarray(val, float), left=0.0, right=0.0)
    if not np.any(out > 0):
        raise SchemaError(f"{where}: {p}: no value between {BAND_NM[0]:g} and {BAND_NM[-1]:g} nm")
    return out


def band_weights(responsivity: NDArray[np.float64], source: NDArray[np.float64]) -> NDArray[np.float64]:
    """Normalised weights (len(:data:`BAND_NM`),) of the band: R S / sum(R S)."""
    w = np.asarray(responsivity, float) * np.asarray(source, float)
    return w / w.sum()


def rgb_band_weights(responsivity: str = DEFAULT_BAND[0], source: str = DEFAULT_BAND[1]) -> NDArray[np.float64]:
    """(3,) weights, summing to 1, of a linear-sRGB albedo's R, G, B in a photodiode's one channel: the band
    (:func:`band_weights` of the named spectra) over the Mallett-Yuksel spectra of R, G and B, as the simulator
    reads an RGB material through a photodiode (silicon x halogen-3000K: 0.452, 0.337, 0.211)."""
    from reconstruction.core.colour import srgb_reflectance_basis

    w = band_weights(spectrum_of(responsivity, "responsivity"), spectrum_of(source, "source"))
    out = w @ srgb_reflectance_basis(BAND_NM)
    return np.asarray(out / out.sum(), dtype=np.float64)


def band_name(responsivity: str, source: str) -> str:
    """The metadata's name of a photodiode band, e.g. ``"silicon x halogen-3000K"`` (CSV paths by file name)."""
    def short(n: str) -> str:
        return Path(n).name if n.lower().endswith(".csv") else n

    return f"{short(responsivity)} x {short(source)}"


def footprint_fraction(theta_i_deg: ArrayLike, beam_diameter_mm: float | None,
                       sample_diameter_mm: float | None) -> NDArray[np.float64]:
    """Fraction (same shape as ``theta_i_deg``) of the beam's power that falls on the sample: 1 where the spot
    (semi-axes A = D / (2 cos theta_i), B = D / 2) fits in the sample's circle (radius R = d / 2), else the exact
    area of ellipse and circle in common over the ellipse's. 1 when either diameter is unknown (None)."""
    ti = np.radians(np.abs(np.asarray(theta_i_deg, dtype=float)))
    if beam_diameter_mm is None or sample_diameter_mm is None:
        return np.ones_like(ti)
    b = 0.5 * beam_diameter_mm
    r = 0.5 * sample_diameter_mm
    a = b / np.maximum(np.cos(ti), 1e-9)
    if b >= r:  # wider than the sample even at normal incidence: the circle lies inside the ellipse
        return np.minimum(r * r / (a * b), 1.0)
    with np.errstate(divide="ignore", invalid="ignore"):
        tan2 = (1.0 / r ** 2 - 1.0 / a ** 2) / (1.0 / b ** 2 - 1.0 / r ** 2)
        phi0 = np.arctan(np.sqrt(np.maximum(tan2, 0.0)))  # where the ellipse crosses the circle
        quarter = 0.5 * r * r * phi0 + 0.5 * a * b * (0.5 * math.pi - np.arctan(a / b * np.tan(phi0)))
        frac = quarter / (0.25 * math.pi * a * b)
    return np.where(a <= r, 1.0, np.clip(frac, 0.0, 1.0))


def footprint_limit_deg(beam_diameter_mm: float | None, sample_diameter_mm: float | None) -> float | None:
    """The incidence (degrees) beyond which the spot overfills the sample (beam / cos theta_i > sample); 0 when it
    overfills at normal incidence already, None when it never does (or a diameter is unknown)."""
    if beam_diameter_mm is None or sample_diameter_mm is None:
        return None
    if beam_diameter_mm >= sample_diameter_mm:
        return 0.0
    return math.degrees(math.acos(beam_diameter_mm / sample_diameter_mm))
