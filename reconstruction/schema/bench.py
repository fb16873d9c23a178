"""The bench file (``configs/*.toml``), declared once: every section, key, type, default, bound and choice that
``gonio-capture`` (:mod:`acquisition.config`) and ``gonio-sim`` (:mod:`simulator.config`) read. Both readers hand
on these structs themselves (no field is copied into a class of their own; ``tests/test_bench_model.py``): the
values they resolve (a default another key implies, the motion hardware, sorted gains) are stored in the fields,
and what a table implies without being a key of it is added by the two views here, :class:`Axis` (an
``[axes.NAME]`` table with its name) and :class:`Detector` (``[detector]`` with its photodiode band). Checks that
need several keys (a port for the transport, the soft limits against the servo's range, the reference geometry
against the collision zone...) live with the readers. Angles in degrees, times in seconds.

The schema lives here, in the base package, because all three packages read the file and the reconstruction may
import neither of the others.
"""


import math
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from reconstruction.schema.simulator import SimulatorSection

__all__ = ["DXL_MODELS", "DXL_BAUDRATES", "AXIS_LETTERS", "MIN_INTEGRATION_TIME_S", "MAX_INTEGRATION_TIME_S",
           "BenchTable", "AxisTable", "GrblTable", "MotionTable", "DetectorTable", "CalibrationTable", "AdaptiveTable",
           "PlanTable", "AxesTables", "BenchFile", "Axis", "Detector"]

#: Dynamixel model names accepted in ``[axes.*].model`` -> model number answered to a ping.
DXL_MODELS = {"XM430-W350": 1020, "XL430-W250": 1060}
#: Baud rates the Dynamixel SDK's PortHandler accepts.
DXL_BAUDRATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000,
                 2000000, 2500000, 3000000, 3500000, 4000000)
#: Default axis letters on the serial text protocol, by axis name.
AXIS_LETTERS = {"light": "L", "detector": "D", "stage": "S"}
#: Integration times the detector protocol accepts (``INT <s>``, docs/serial-protocol.md), seconds.
MIN_INTEGRATION_TIME_S, MAX_INTEGRATION_TIME_S = 1e-5, 10.0


def _pos_within(lo: float, hi: float, unit: str = "") -> Any:
    """The check "> 0, then within [lo, hi]" (two messages, as a person reads them)."""
    def check(v: float) -> str | None:
        if not v > 0:
            return f"must be > 0, got {v:g}"
        return None if lo <= v <= hi else f"must lie in [{lo:g}, {hi:g}]{unit}, got {v:g}"
    return check


def _num(lo: float | None = None, hi: float | None = None, *, gt: float | None = None, description: str = "",
         check: Any = None) -> Meta:
    extra = {"check": check} if check is not None else {}
    return Meta(ge=lo, le=hi, gt=gt, description=description, extra=extra)


Angle = Annotated[float, _num(-180.0, 180.0, description="degrees")]
Positive = Annotated[float, _num(gt=0.0)]


class BenchTable(msgspec.Struct, kw_only=True, frozen=True, forbid_unknown_fields=True):
    """``[bench]``: transport, ports and the geometry constraints of the arms."""

    name: Annotated[str, Meta(description="name of the bench (logs, slice metadata)")] = "bench"
    transport: Annotated[Literal["dynamixel", "serial", "simulated"], Meta(
        description="dynamixel: servos on a Dynamixel bus + serial detector; serial: a stepper controller that "
                    "also reads the detector; simulated: gonio-sim in a child process")]
    motion: Annotated[Literal["dynamixel", "serial", "grbl"] | None, Meta(
        description="motion hardware of a simulated bench (real benches: equal to transport, or left out; "
                    '"grbl": stepper arms on a GRBL 1.1 controller, as [motion].type = "grbl")')] = None
    dynamixel_port: Annotated[str, Meta(description='servo bus port, e.g. "/dev/ttyUSB0"')] = ""
    dynamixel_baudrate: Annotated[Literal[DXL_BAUDRATES], Meta(description="servo bus baud rate")] = 1000000  # type: ignore[valid-type]
    serial_port: Annotated[str, Meta(description='controller / detector port, e.g. "/dev/ttyACM0"')] = ""
    serial_baudrate: Annotated[int, _num(50, 100_000_000, check=_pos_within(50, 1e8))] = 115200
    serial_timeout_s: Annotated[float, _num(1e-3, 60, check=_pos_within(1e-3, 60))] = 1.0
    min_separation_deg: Annotated[float, _num(0.0, 90.0, description="arms closer than this in |theta_i + theta_o| "
                                                                     "collide (degrees)")]
    blind_spot_half_width_deg: Annotated[float, _num(0.0, 90.0, description="the source arm shadows the detector "
                                                                            "within this of the retro direction")]
    simulator_command: Annotated[str, Meta(description="the simulator program (simulated benches)")] = "gonio-sim"
    source_divergence_deg: Annotated[float, _num(0.0, 10.0, description="half angle of the source's beam "
                                                                        "divergence (degrees)")] = 0.0
    beam_diameter_mm: Annotated[float, _num(gt=0.0, hi=1000.0, check=_pos_within(1e-3, 1000, " mm"),
                                            description="diameter of the beam at normal incidence (mm)")] | None = None
    sample_diameter_mm: Annotated[float, _num(gt=0.0, hi=1000.0, check=_pos_within(1e-3, 1000, " mm"),
                                              description="diameter of the sample (mm)")] | None = None
    source_spectrum: Annotated[str, Meta(description='"halogen-3000K" (built in), "D65", or a wavelength_nm,value '
                                                     "CSV (relative to the bench file)")] = "halogen-3000K"
    detector_distance_mm: Annotated[float, _num(gt=0.0, hi=10000.0, check=_pos_within(1.0, 10000, " mm"),
                                                description="distance from the rotation axis to the detector's "
                                                            "aperture (mm; gonio-align's surface offset)")
                                    ] | None = None


def _units_per_deg(v: float) -> str | None:
    if not v > 0:
        return f"must be > 0, got {v:g}"
    return None if 1e-2 <= v <= 1e6 else f"must lie in [0.01, 1e+06] units per degree, got {v:g}"


class AxisTable(msgspec.Struct, kw_only=True, frozen=True, forbid_unknown_fields=True):
    """``[axes.light]``, ``[axes.detector]``, ``[axes.stage]``: controller units = zero_offset + direction *
    units_per_deg * degrees."""

    id: Annotated[int | str, Meta(description="Dynamixel ID (0-252) or the axis letter on the serial controller",
                                  extra={"expected": "an integer ID or an axis letter"})]
    model: Annotated[str | None, Meta(description=f"Dynamixel model: {', '.join(DXL_MODELS)}")] = None
    units_per_deg: Annotated[float, _num(1e-2, 1e6, check=_units_per_deg, description="controller units per degree")]
    zero_offset: Annotated[float, _num(-1e9, 1e9, description="controller position of 0 degrees")]
    direction: Annotated[Literal[1, -1], Meta(description="+1 or -1")]
    min_deg: Annotated[float, _num(-180.0, 180.0, description="soft limit (degrees)")]
    max_deg: Annotated[float, _num(-180.0, 180.0, description="soft limit (degrees)")]
    park_deg: Annotated[float, _num(-180.0, 180.0, description="park position (degrees)")]

    def deg_to_units(self, deg: float) -> float:
        """Axis angle (deg) -> controller units (not rounded)."""
        return self.zero_offset + self.direction * self.units_per_deg * deg

    def units_to_deg(self, units: float) -> float:
        """Controller units -> axis angle (deg)."""
        return (units - self.zero_offset) / (self.direction * self.units_per_deg)

    def within(self, deg: float, eps: float = 1e-9) -> bool:
        """``deg`` within the soft limits ``[min_deg, max_deg]`` (to ``eps``)."""
        return self.min_deg - eps <= deg <= self.max_deg + eps


class GrblTable(msgspec.Struct, kw_only=True, frozen=True, forbid_unknown_fields=True):
    """``[motion.grbl]``: the GRBL 1.1 controller of a stepper bench (X = light arm, Y = detector arm; GRBL's
    "mm" are degrees: ``$100``/``$101`` = ``[axes.*].units_per_deg`` steps per degree, ``$110``/``$111`` =
    60 x ``[motion].velocity_deg_s`` deg/min, ``$120``/``$121`` = ``[motion].acceleration_deg_s2``)."""

    port: Annotated[str, Meta(description='GRBL\'s serial port, e.g. "/dev/ttyUSB0" (real benches)')] = ""
    baudrate: Annotated[int, _num(50, 100_000_000, check=_pos_within(50, 1e8))] = 115200
    homing: Annotated[bool, Meta(description="the arms have homing switches: $22 = 1, and $H homes them before "
                                             "anything moves")] = False
    soft_limits: Annotated[bool, Meta(description="GRBL's soft limits: $20 = 1 and $130/$131 the arms' travel "
                                                  "from the home switch (needs homing)")] = False
    unlock: Annotated[bool, Meta(description="after an alarm on a bench without switches, unlock with $X on "
                                             "purpose (you checked the arms are where GRBL believes them)")] = False
    boot_s: Annotated[float, _num(0.0, 30.0, description="wait for GRBL's welcome line after opening the port "
                                                         "(an Uno resets when its port opens)")] = 2.5


class MotionTable(msgspec.Struct, kw_only=True, frozen=True, forbid_unknown_fields=True):
    """``[motion]``: profiles (Dynamixel units), stepper speeds, tolerance, settling, timeouts, retries."""

    type: Annotated[Literal["dynamixel", "serial", "grbl"] | None, Meta(
        description='the motion hardware: "grbl" (stepper arms on GRBL 1.1, [motion.grbl]); default: '
                    "[bench].motion, else the transport")] = None
    grbl: GrblTable | None = None

    profile_velocity: Annotated[int, _num(0, 32767, description="Dynamixel Profile Velocity (0.229 rev/min "
                                                                       "units, 0 = unlimited)")] | None = None
    profile_acceleration: Annotated[int, _num(0, 32767, description="Dynamixel Profile Acceleration "
                                                                           "(214.577 rev/min^2 units)")] | None = None
    velocity_deg_s: Annotated[float, _num(1e-3, 1e5, check=_pos_within(1e-3, 1e5), description="stepper speed")] = 60.0
    acceleration_deg_s2: Annotated[float, _num(1e-3, 1e7, check=_pos_within(1e-3, 1e7))] = 240.0
    tolerance_deg: Annotated[float, _num(gt=0.0, description="in position within this (degrees, at most 5)")]
    settle_s: Annotated[float, _num(0.0, 60.0, description="wait after a move before reading (s)")]
    timeout_s: Annotated[float, _num(1e-3, 3600, check=_pos_within(1e-3, 3600))] = 20.0
    retries: Annotated[int, _num(0, 100, description="retries of a failed transaction")] = 3
    poll_interval_s: Annotated[float, _num(0.0, 10.0)] = 0.01


def _gains_check(v: tuple[float, ...]) -> str | None:
    if not 1 <= len(v) <= 12:
        return f"expected 1 to 12 gains, got {len(v)}"
    if any(not 1e-3 <= g <= 1e7 for g in v):
        return f"every gain must lie in [0.001, 1e+07], got {v!r}"
    if len(set(v)) != len(v):
        return f"gains must differ, got {v!r}"
    return None


class DetectorTable(msgspec.Struct, kw_only=True, frozen=True, forbid_unknown_fields=True):
    """``[detector]``: type, integration time per repeat, repeats, saturation, dark repeats, auto-ranging."""

    type: Annotated[Literal["photodiode", "spectrometer", "seabreeze", "pm100"], Meta(
        description="photodiode or spectrometer: on the detector board (serial protocol); seabreeze: an Ocean "
                    "Insight spectrometer through python-seabreeze; pm100: a Thorlabs PM100 power meter through "
                    "pyvisa (docs/detectors.md)")]
    integration_time_s: Annotated[float, _num(MIN_INTEGRATION_TIME_S, MAX_INTEGRATION_TIME_S)]
    repeats: Annotated[int, _num(1, 1000)]
    saturation: Annotated[float, _num(1, 2.0**32, check=_pos_within(1, 2.0**32), description="raw counts (the "
                                                                                            "seabreeze and pm100 "
                                                                                            "types read it from "
                                                                                            "the device)")
                          ] | None = None
    dark_repeats: Annotated[int, _num(1, 1000)] = 32
    auto_range: Annotated[bool, Meta(description="read saturated points again at shorter integration times")] = True
    min_integration_time_s: Annotated[float, _num(MIN_INTEGRATION_TIME_S, MAX_INTEGRATION_TIME_S)] = \
        MIN_INTEGRATION_TIME_S
    solid_angle_sr: Annotated[float, _num(0.0, 0.5, description="acceptance of the detector cone (sr); 0 = a point "
                                                               "detector")] | None = None
    aperture_half_angle_deg: Annotated[float, _num(0.0, 23.0, description="half angle of the detector cone "
                                                                          "(degrees), instead of solid_angle_sr")
                                       ] | None = None
    responsivity: Annotated[str, Meta(description='photodiode band: "silicon" (built in) or a '
                                                  "wavelength_nm,responsivity CSV")] = "silicon"
    gains: Annotated[tuple[float, ...] | None, Meta(description="the amplifier's switchable gains, e.g. [1, 10, 100, "
                                                          "1000, 10000] (GAIN n); auto-ranging uses them all",
                                              extra={"check": _gains_check})] = None
    chop: Annotated[bool, Meta(description="the detector board chops the source (CHOP ON): readings are on-minus-off "
                                           "sums in which room light, its flicker and the amplifier's offset "
                                           "cancel (docs/serial-protocol.md; an LED source)")] = False
    monitor: Annotated[bool, Meta(description="ratio readings: the detector board reports its monitor photodiode "
                                              "(firmware built with MONITOR=1, a photodiode on A1 seeing the "
                                              "source) and every net signal is divided by the source's power then "
                                              "relative to the white reference's (its drift divides out; relative "
                                              "calibration)")] = False
    serial_number: Annotated[str, Meta(description='seabreeze: the spectrometer\'s serial number (default: the '
                                                   "first one found)")] | None = None
    correct_dark_counts: Annotated[bool, Meta(description="seabreeze: subtract the electrical dark pixels' level "
                                                          "when the device has them")] = True
    correct_nonlinearity: Annotated[bool, Meta(description="seabreeze: apply the device's non-linearity "
                                                           "coefficients when it stores them")] = True
    source_off: Annotated[Literal["auto", "board", "shutter", "prompt"], Meta(
        description="seabreeze and pm100: how a dark reading turns the source off: the detector board's SOURCE "
                    "pin, the spectrometer's shutter, or a prompt to the operator; auto: the first the bench "
                    "has")] = "auto"
    resource: Annotated[str, Meta(description='pm100: the VISA resource, e.g. "USB0::0x1313::0x8078::P0001234::'
                                              'INSTR" (default: the first Thorlabs PM100 found)')] | None = None
    wavelength_nm: Annotated[float, _num(100.0, 20000.0, description="pm100: the wavelength correction "
                                                                     "(SENS:CORR:WAV, nm); default: the centroid "
                                                                     "of the source seen by the sensor's band")
                             ] | None = None

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


class CalibrationTable(msgspec.Struct, kw_only=True, frozen=True, forbid_unknown_fields=True):
    """``[calibration]``: relative (a white reference) or absolute (source power x detector solid angle)."""

    mode: Literal["relative", "absolute"]
    reference_reflectance: Annotated[float, Meta(gt=0.0, le=1.5)] | None = None
    reference_spectrum: Annotated[str | None, Meta(description="wavelength_nm,reflectance CSV of the reference, "
                                                               "relative to the bench file")] = None
    reference_theta_i_deg: Annotated[float, _num(-89.9, 89.9)] | None = None
    reference_theta_o_deg: Annotated[float, _num(-89.9, 89.9)] | None = None
    reference_repeats: Annotated[int, _num(1, 1000)] = 32
    gain_ratios: Annotated[Literal["measured", "nominal"], Meta(description=(
        '"measured": the amplifier\'s gain ratios measured on the white reference at every gain where it reads '
        'clean and above the noise, used instead of the nominal [detector].gains; "nominal": taken as exact'))
    ] = "measured"
    warmup_readings: Annotated[int, _num(0, 1000, description="warm-up check before the calibration: this many "
                                                              "readings of the white reference in a row must "
                                                              "agree within warmup_max_drift; 0 = no check")] = 0
    warmup_interval_s: Annotated[float, _num(0.0, 3600.0, description="bench time between the warm-up check's "
                                                                      "readings")] = 10.0
    warmup_max_drift: Annotated[float, _num(1e-6, 1.0, description="the largest relative change between two "
                                                                   "warm-up readings of a source that has "
                                                                   "warmed up")] = 0.002
    warmup_timeout_s: Annotated[float, _num(0.0, 86400.0, description="give up (an error) when the source has "
                                                                      "not settled after this long")] = 1800.0
    source_power: Annotated[float, _num(1e-6, 1e18, check=_pos_within(1e-6, 1e18))] | None = None
    detector_solid_angle_sr: Annotated[float, _num(1e-12, 2 * math.pi,
                                                          check=_pos_within(1e-12, 2 * math.pi))] | None = None


class AdaptiveTable(msgspec.Struct, frozen=True, forbid_unknown_fields=True):
    """``[plan.adaptive]``: a coarse pass, then midpoints where the slice changes fast."""

    enabled: bool = True
    coarse_step_deg: Annotated[float, _num(gt=0.0, description="default: 4 x theta_o_step_deg")] | None = None
    min_step_deg: Annotated[float, _num(gt=0.0)] = 0.5
    tolerance: Annotated[float, _num(gt=0.0, description="relative interpolation error that splits a gap")] = 0.05
    time_budget_s: Annotated[float, _num(0.0)] = 0.0
    max_points: Annotated[int, _num(0)] = 0
    max_rounds: Annotated[int, _num(1, 50)] = 6


class PlanTable(msgspec.Struct, kw_only=True, frozen=True, forbid_unknown_fields=True):
    """``[plan]``: incidences, the outgoing range and step (or explicit points), repeats, options."""

    theta_i_deg: Annotated[tuple[float, ...] | None, Meta(description="incidence angles (degrees)")] = None
    theta_i_min_deg: float | None = None
    theta_i_max_deg: float | None = None
    theta_i_step_deg: Annotated[float, _num(gt=0.0)] | None = None
    theta_o_min_deg: Annotated[float, _num(-90.0, 90.0)] | None = None
    theta_o_max_deg: Annotated[float, _num(-90.0, 90.0)] | None = None
    theta_o_step_deg: Annotated[float, _num(gt=0.0)] | None = None
    points: Annotated[tuple[tuple[float, float], ...] | None, Meta(description="explicit [theta_i_deg, theta_o_deg] "
                                                                         "pairs instead of a grid")] = None
    repeats: Annotated[int, _num(1, 1000, description="default: [detector].repeats")] | None = None
    dark_at_end: bool = True
    order: Literal["optimized", "naive"] = "optimized"
    strict: Annotated[bool, Meta(description="refuse collision / blind-spot points instead of skipping them")] = False
    scene: Annotated[str | None, Meta(description="scene file restricting the plan")] = None
    sample_name: str | None = None
    adaptive: AdaptiveTable | None = None


class AxesTables(msgspec.Struct, forbid_unknown_fields=True):
    """``[axes]``: the light and detector arms and an optional sample stage."""

    light: AxisTable
    detector: AxisTable
    stage: AxisTable | None = None


class BenchFile(msgspec.Struct, forbid_unknown_fields=True):
    """A bench file: ``gonio-capture --config`` and ``gonio-sim serve --config`` read it."""

    bench: BenchTable
    axes: AxesTables
    motion: MotionTable
    detector: DetectorTable
    calibration: CalibrationTable
    plan: PlanTable
    material: Annotated[dict[str, Any] | None, Meta(
        description="the simulated sample (a simulated bench needs it): see docs/schema/material.json")] = None
    simulator: SimulatorSection | None = None



# --- what a table implies, as both readers hand it on -------------------------------------------------------------


class Axis(AxisTable, kw_only=True):
    """An ``[axes.NAME]`` table with its name (``"light"``, ``"detector"``, ``"stage"``): the axis both readers
    hand to the drivers. ``controller units = zero_offset + direction * units_per_deg * degrees``."""

    name: str

    @property
    def letter(self) -> str:
        """Axis letter on the serial text protocol: ``id`` when it is a string, else L/D/S by axis name."""
        if isinstance(self.id, str) and self.id:
            return self.id.upper()
        return AXIS_LETTERS.get(self.name, self.name[:1].upper())

    @property
    def model_number(self) -> int:
        """The Dynamixel model number a servo of ``model`` answers to a ping (ValueError for another model)."""
        try:
            return DXL_MODELS[self.model or ""]
        except KeyError:
            raise ValueError(f"axis {self.name}: unknown Dynamixel model {self.model!r}") from None


class Detector(DetectorTable, kw_only=True):
    """``[detector]`` with what its keys imply: ``band_weights``, the photodiode band (``responsivity`` x
    ``[bench].source_spectrum``) on :data:`reconstruction.schema.optics.BAND_NM` (None: not a photodiode)."""

    band_weights: Any = None

    @property
    def kind(self) -> str:
        """What the detector measures: ``"spectrometer"`` (the board's or a seabreeze) or ``"photodiode"`` (the
        board's or a pm100 head)."""
        return {"seabreeze": "spectrometer", "pm100": "photodiode"}.get(self.type, self.type)
