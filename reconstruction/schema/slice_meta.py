"""The metadata line of a slice file (``# meta: {...}``, docs/slice-format.md), declared once. Readers require
``format_version`` and ``quantity``; a capture writes the rest (and may add more)."""

from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

__all__ = ["FORMAT_VERSION", "QUANTITIES", "SliceMeta"]

FORMAT_VERSION = 1
#: What the value columns hold: f_r (1/sr), pi f_r, or f_r cos theta_o.
QUANTITIES = ("brdf", "reflectance_factor", "brdf_cos")


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
