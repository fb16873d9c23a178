"""The sections of a bench file as the acquisition reads them: one frozen dataclass per table (``[axes.*]``,
``[bench]``, ``[motion]``, ``[detector]``, ``[calibration]``). :mod:`acquisition.config` reads and validates them
(and re-exports them); :mod:`acquisition.plans.planconfig` reads ``[plan]`` against the axes and the detector. Angles in
degrees, times in seconds.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from reconstruction.schema.bench import AXIS_LETTERS

__all__ = ["AxisConfig", "BenchSection", "MotionConfig", "DetectorConfig", "CalibrationConfig"]


@dataclass(frozen=True)
class AxisConfig:
    """One rotary axis: controller units = ``zero_offset + direction * units_per_deg * deg``."""

    name: str
    id: int | str
    model: str | None
    units_per_deg: float
    zero_offset: float
    direction: int
    min_deg: float
    max_deg: float
    park_deg: float

    @property
    def letter(self) -> str:
        """Axis letter on the serial text protocol: ``id`` when it is a string, else L/D/S by axis name."""
        if isinstance(self.id, str):
            return self.id.upper()
        return AXIS_LETTERS.get(self.name, self.name[:1].upper())

    def deg_to_units(self, deg: float) -> float:
        """Axis angle (deg) -> controller units (not rounded)."""
        return self.zero_offset + self.direction * self.units_per_deg * deg

    def units_to_deg(self, units: float) -> float:
        """Controller units -> axis angle (deg)."""
        return (units - self.zero_offset) / (self.direction * self.units_per_deg)

    def within(self, deg: float, eps: float = 1e-9) -> bool:
        return self.min_deg - eps <= deg <= self.max_deg + eps


@dataclass(frozen=True)
class BenchSection:
    """``[bench]``: transport, ports and the geometry constraints of the arms."""

    name: str
    transport: str
    motion: str                        # "dynamixel" | "serial": which motion hardware is driven
    dynamixel_port: str
    dynamixel_baudrate: int
    serial_port: str
    serial_baudrate: int
    serial_timeout_s: float
    min_separation_deg: float
    blind_spot_half_width_deg: float
    simulator_command: str
    source_divergence_deg: float = 0.0
    beam_diameter_mm: float | None = None
    sample_diameter_mm: float | None = None
    source_spectrum: str = "halogen-3000K"
    detector_distance_mm: float | None = None


@dataclass(frozen=True)
class MotionConfig:
    """``[motion]``: profiles (Dynamixel units), stepper speeds (deg/s, deg/s^2), tolerance, settle, retries."""

    profile_velocity: int
    profile_acceleration: int
    velocity_deg_s: float
    acceleration_deg_s2: float
    tolerance_deg: float
    settle_s: float
    timeout_s: float
    retries: int
    poll_interval_s: float
    type: str | None = None            # "grbl" for a GRBL stepper bench ([motion].type)
    grbl: Any = None                   # [motion.grbl] (reconstruction.schema.bench.GrblTable) of a GRBL bench


@dataclass(frozen=True)
class DetectorConfig:
    """``[detector]``: type, integration time per repeat (s), default repeats, saturation (raw counts), dark
    repeats, and auto-ranging: with ``auto_range`` a saturated reading is taken again at shorter integration
    times, down to ``min_integration_time_s`` (s), and converted back to ``integration_time_s``."""

    type: str
    integration_time_s: float
    repeats: int
    saturation: float | None                   # None: read from the device (seabreeze, pm100)
    dark_repeats: int
    auto_range: bool = True
    min_integration_time_s: float = 1e-5
    solid_angle_sr: float | None = None        # acceptance of the detector cone (sr); None: not given
    aperture_half_angle_deg: float | None = None
    responsivity: str = "silicon"
    gains: tuple[float, ...] | None = None     # the amplifier's gains, ascending; None: the gain is not switched
    band_weights: Any = field(default=None, repr=False)  # photodiode: weights on reconstruction.schema.optics.BAND_NM
    serial_number: str | None = None           # seabreeze: the spectrometer (None: the first found)
    correct_dark_counts: bool = True           # seabreeze: electrical-dark correction when the device offers it
    correct_nonlinearity: bool = True          # seabreeze: non-linearity correction when the device offers it
    source_off: str = "auto"                   # seabreeze, pm100: "auto", "board", "shutter" or "prompt"
    resource: str | None = None                # pm100: the VISA resource (None: the first PM100 found)
    wavelength_nm: float | None = None         # pm100: SENS:CORR:WAV (nm); None: the band's centroid
    chop: bool = False                         # the detector board chops the source (CHOP ON)

    @property
    def on_board(self) -> bool:
        """True for the detector board's own detectors (photodiode, spectrometer: the serial protocol)."""
        return self.type in ("photodiode", "spectrometer")

    @property
    def acceptance_sr(self) -> float:
        """The detector cone's solid angle (sr): ``solid_angle_sr``, or from ``aperture_half_angle_deg``, or 0 (a
        point detector: not given)."""
        if self.solid_angle_sr is not None:
            return self.solid_angle_sr
        if self.aperture_half_angle_deg is not None:
            return 2 * math.pi * (1 - math.cos(math.radians(self.aperture_half_angle_deg)))
        return 0.0


@dataclass(frozen=True)
class CalibrationConfig:
    """``[calibration]``: relative (white reference) or absolute (source power and detector solid angle)."""

    mode: str
    reference_reflectance: float | None
    reference_spectrum: tuple[tuple[float, ...], tuple[float, ...]] | None  # (wavelengths_nm, reflectance)
    reference_spectrum_path: str | None
    reference_theta_i_deg: float
    reference_theta_o_deg: float
    reference_repeats: int
    source_power: float | None
    detector_solid_angle_sr: float | None
    gain_ratios: str = "measured"
    warmup_readings: int = 0
    warmup_interval_s: float = 10.0
    warmup_max_drift: float = 0.002
    warmup_timeout_s: float = 1800.0

    def to_meta(self) -> dict[str, Any]:
        d: dict[str, Any] = {"mode": self.mode}
        if self.mode == "relative":
            if self.reference_spectrum_path:
                d["reference_spectrum"] = self.reference_spectrum_path
            else:
                d["reference_reflectance"] = self.reference_reflectance
            d["reference_theta_i_deg"] = self.reference_theta_i_deg
            d["reference_theta_o_deg"] = self.reference_theta_o_deg
        else:
            d["source_power"] = self.source_power
            d["detector_solid_angle_sr"] = self.detector_solid_angle_sr
        return d
