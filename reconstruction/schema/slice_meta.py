"""The metadata line of a slice file (``# meta: {...}``, docs/formats.md), declared once. Readers require
``format_version`` and ``quantity``; a capture writes the rest (and may add more)."""

import math
from collections.abc import Mapping
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

__all__ = ["FORMAT_VERSION", "QUANTITIES", "SliceMeta", "InstrumentMeta", "INSTRUMENT_KEYS", "check_instrument"]

FORMAT_VERSION = 1
#: What the value columns hold: f_r (1/sr), pi f_r, or f_r cos theta_o.
QUANTITIES = ("brdf", "reflectance_factor", "brdf_cos")


#: the keys of the ``instrument`` object (reconstruction.instrument.response.Instrument.to_meta())
INSTRUMENT_KEYS = ("detector_solid_angle_sr", "source_divergence_deg", "beam_diameter_mm", "sample_diameter_mm",
                   "band")


class InstrumentMeta(msgspec.Struct):
    """The instrument's optics (reconstruction.instrument.response.Instrument); no ``instrument``: a point one."""

    detector_solid_angle_sr: Annotated[float, Meta(ge=0.0, le=2 * math.pi, description="the detector cone's "
                                                   "acceptance, sr (0 = a point detector)")] = 0.0
    source_divergence_deg: Annotated[float, Meta(ge=0.0, le=45.0, description="the beam's half angle of "
                                                 "divergence, deg (0 = collimated)")] = 0.0
    beam_diameter_mm: Annotated[float, Meta(gt=0.0, description="the beam's diameter at normal incidence, mm")
                                ] | None = None
    sample_diameter_mm: Annotated[float, Meta(gt=0.0, description="the sample's diameter, mm")] | None = None
    band: Annotated[str, Meta(min_length=1, description="what the value channels are: rgb, spectral, or e.g. "
                                                        "'silicon x halogen-3000K' (one responsivity-weighted "
                                                        "channel)")] = "rgb"


def _number(d: Mapping[str, Any], key: str, where: str, default: float | None, lo: float, hi: float,
            optional: bool = False) -> float | None:
    v = d.get(key, default)
    if v is None and optional:
        return None
    if isinstance(v, bool) or not isinstance(v, (int, float)) or not math.isfinite(v) or not lo <= v <= hi:
        raise ValueError(f"{where}.{key}: expected a number in [{lo:g}, {hi:g}]{' or null' if optional else ''}, "
                         f"got {v!r}")
    return float(v)


def check_instrument(d: Any, where: str = "instrument") -> dict[str, Any]:
    """The ``instrument`` object checked and completed with its defaults; ValueError naming the key if malformed.

    >>> check_instrument({"detector_solid_angle_sr": 1e-3})["band"]
    'rgb'
    """
    if not isinstance(d, Mapping):
        raise ValueError(f"{where}: expected an object with the keys {', '.join(INSTRUMENT_KEYS)}, got {d!r}")
    band = d.get("band", "rgb")
    if not isinstance(band, str) or not band.strip():
        raise ValueError(f"{where}.band: expected a non-empty string (\"rgb\", \"spectral\" or e.g. "
                         f"\"silicon x halogen-3000K\"), got {band!r}")
    return {
        "detector_solid_angle_sr": _number(d, "detector_solid_angle_sr", where, 0.0, 0.0, 2 * math.pi),
        "source_divergence_deg": _number(d, "source_divergence_deg", where, 0.0, 0.0, 45.0),
        "beam_diameter_mm": _number(d, "beam_diameter_mm", where, None, 1e-9, 1e6, optional=True),
        "sample_diameter_mm": _number(d, "sample_diameter_mm", where, None, 1e-9, 1e6, optional=True),
        "band": band,
    }


class SliceMeta(msgspec.Struct, omit_defaults=True):
    """The metadata of a slice file (other keys are kept as they are)."""

    format_version: Annotated[Literal[1], Meta(description="the slice format's version")]
    quantity: Annotated[Literal[QUANTITIES], Meta(description="brdf (f_r, 1/sr), reflectance_factor (pi f_r) or "  # type: ignore[valid-type]
                                                              "brdf_cos (f_r cos theta_o)")]
    material: str | None = None
    bench: Annotated[str, Meta(description="the bench file of the capture")] | None = None
    bench_name: str | None = None
    transport: str | None = None
    software_version: str | None = None
    calibration: Annotated[dict[str, Any], Meta(description="mode, reference or absolute constants, dark and "
                                                            "reference readings")] | None = None
    detector: dict[str, Any] | None = None
    plan: dict[str, Any] | None = None
    plan_fingerprint: str | None = None
    config_fingerprint: Annotated[dict[str, Any], Meta(description="every setting that changes what a sample "
                                                                   "means, {\"[section].key\": value}")] | None = None
    config_settings: dict[str, Any] | None = None
    unmeasurable: list[list[Any]] | None = None
    started: str | None = None
    blind_spot_half_width_deg: float | None = None
    instrument: Annotated[InstrumentMeta, Meta(description="the instrument's optics (docs/instrument.md); missing "
                                                          "= a point instrument")] | None = None
