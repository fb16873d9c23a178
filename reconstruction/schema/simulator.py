"""The simulator's sections of the bench file, declared once: ``[simulator]``, ``[simulator.faults]`` and
``[simulator.spectrometer]`` (all optional). Beyond the sign, every number is bounded so that no value that
passes can make the virtual bench hang, overflow or allocate without bound (a 1e-300 time scale, 1e300
aperture samples, a 1e-9 nm spectrometer step). :mod:`simulator.config` reads them with these structs.
"""


import math
from collections.abc import Callable
from typing import Annotated, Any, Literal

import msgspec
from msgspec import Meta

from reconstruction.schema.core import describe

__all__ = ["FaultsSection", "SpectrometerSection", "MisalignmentSection", "SimulatorSection"]


def _checks(*rules: tuple[Callable[[Any], bool], str]) -> Callable[[Any], str | None]:
    """The first rule a value breaks, as "WHAT, got VALUE"."""
    def check(v: Any) -> str | None:
        for ok, what in rules:
            if not ok(v):
                return f"{what}, got {describe(v)}"
        return None
    return check


_NONNEG = (lambda v: v >= 0, "must be >= 0")
_POS = (lambda v: v > 0, "must be > 0")


def _within(lo: float, hi: float) -> tuple[Callable[[Any], bool], str]:
    return (lambda v: lo <= v <= hi, f"must lie in [{lo:g}, {hi:g}]")


def _m(lo: float | None, hi: float | None, *rules: tuple[Callable[[Any], bool], str], description: str = "") -> Meta:
    return Meta(ge=lo, le=hi, description=description, extra={"check": _checks(*rules)})


Rate = Annotated[float, _m(0.0, 1.0, (lambda v: 0.0 <= v <= 1.0, "must lie in [0, 1]"), description="probability")]


class FaultsSection(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """``[simulator.faults]``: rates are probabilities (per reply packet, per byte, per move, per reading)."""

    drop_reply_rate: Rate = 0.0       # per status packet / per reply line block
    corrupt_byte_rate: Rate = 0.0     # per transmitted reply byte
    overload_rate: Rate = 0.0         # per servo move: overload error during the move
    stall_rate: Rate = 0.0            # per move: the axis stops partway
    saturate_rate: Rate = 0.0         # per detector reading (repeat): the reading clips
    port_vanish_after_s: Annotated[float, _m(0.0, None, _NONNEG, description="simulated seconds; 0 = never")] = 0.0
    vanish_ports: Annotated[str, Meta(description='"all", "dynamixel" or "serial"', extra={"check": _checks(
        (lambda v: v in ("all", "dynamixel", "serial"), 'must be "all", "dynamixel" or "serial"'))})] = "all"
    serial_comm_faults: Annotated[bool, Meta(description="drop/corrupt on the serial text port as well")] = False
    stall_overload_s: Annotated[float, _m(0.0, 3600.0, _NONNEG, _within(0, 3600))] = 1.0


class SpectrometerSection(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """``[simulator.spectrometer]``: the wavelength grid in nm (inclusive range)."""

    wl_min_nm: Annotated[float, _m(100.0, 3000.0, _within(100, 3000))] = 380.0
    wl_max_nm: Annotated[float, _m(100.0, 3000.0, _within(100, 3000))] = 780.0
    wl_step_nm: Annotated[float, _m(0.1, 1000.0, _POS, _within(0.1, 1000))] = 5.0

    def grid(self) -> Any:
        import numpy as np

        n = int(math.floor((self.wl_max_nm - self.wl_min_nm) / self.wl_step_nm + 1e-9)) + 1
        return self.wl_min_nm + self.wl_step_nm * np.arange(n)


class MisalignmentSection(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """``[simulator.misalignment]``: a bench out of alignment, for ``gonio-align`` to find
    (:mod:`reconstruction.instrument.alignment`; docs/build-a-bench.md, Alignment). Degrees and mm."""

    light_zero_deg: Annotated[float, _m(-10.0, 10.0, _within(-10, 10), description="the light arm stands this far "
                                                                                   "past its reading")] = 0.0
    detector_zero_deg: Annotated[float, _m(-10.0, 10.0, _within(-10, 10), description="the detector arm stands "
                                                                                     "this far past its reading")] = 0.0
    sample_tilt_deg: Annotated[float, _m(-10.0, 10.0, _within(-10, 10), description="the sample's normal tilted in "
                                                                                   "the plane, towards the "
                                                                                   "detector's side")] = 0.0
    reference_tilt_deg: Annotated[float, _m(-10.0, 10.0, _within(-10, 10), description="the white reference's "
                                                                                      "normal, likewise")] = 0.0
    surface_offset_mm: Annotated[float, _m(-20.0, 20.0, _within(-20, 20), description="the sample's surface this "
                                                                                     "far above the rotation axis "
                                                                                     "(towards the arms)")] = 0.0
    sample_turned: Annotated[bool, Meta(description="the sample turned 180 deg about its normal in its holder "
                                                    "(its tilt reversed)")] = False

    @property
    def active(self) -> bool:
        return any((self.light_zero_deg, self.detector_zero_deg, self.sample_tilt_deg, self.reference_tilt_deg,
                    self.surface_offset_mm))


class SimulatorSection(msgspec.Struct, kw_only=True, forbid_unknown_fields=True):
    """``[simulator]``: the virtual bench's physics, noise, timing and faults."""

    seed: Annotated[int, _m(0, 2**63 - 1, (lambda v: 0 <= v < 2**63, "must lie in [0, 2**63)"))] = 1
    time_scale: Annotated[float, _m(0.0, 1e6, _NONNEG, (lambda v: v == 0 or 1e-3 <= v <= 1e6,
                                                        "must be 0 (as fast as possible) or lie in [0.001, 1e+06]"),
                                    description="simulated seconds per wall second; 0 = as fast as possible")] = 0.0
    source_power: Annotated[float, _m(0.0, 1e15, _NONNEG, _within(0, 1e15), description="counts per 1/sr sr")] = 1.0e6
    detector_solid_angle_sr: Annotated[float, _m(0.0, 0.5, _NONNEG, (lambda v: v <= 0.5, "must lie in [0, 0.5] sr"),
                                                 description="older name of [detector].solid_angle_sr")] | None = None
    dark_offset: Annotated[float, _m(0.0, 1e9, _NONNEG, _within(0, 1e9))] = 200.0
    read_noise: Annotated[float, _m(0.0, 1e9, _NONNEG, _within(0, 1e9))] = 5.0
    shot_noise: bool = True
    adc_bits: Annotated[int, _m(1, 32, (lambda v: 1 <= v <= 32, "must lie in [1, 32]"))] = 16
    gain: Annotated[float, _m(1e-6, 1e7, _POS, _within(1e-6, 1e7), description="gain at power-up")] = 1.0
    input_noise: Annotated[float, _m(0.0, 1e6, _NONNEG, _within(0, 1e6), description="amplifier noise referred "
                                                                                       "to its input (counts rms "
                                                                                       "at gain 1)")] = 0.0
    input_offset: Annotated[float, _m(0.0, 1e6, _NONNEG, _within(0, 1e6), description="amplifier offset referred "
                                                                                         "to its input (counts at "
                                                                                         "gain 1)")] = 0.0
    electrons_per_count: Annotated[float, _m(1e-3, 1e9, _POS, _within(1e-3, 1e9), description="photo-electrons "
                                                                                               "per count at gain 1 "
                                                                                               "(shot noise)")] = 1.0
    frontend: Annotated[Literal["ideal", "netlist"], Meta(
        description="the photodiode amplifier: 'ideal' (gain x signal + dark_offset) or 'netlist' (the circuit's "
                    "transfer from hardware/frontend/transfer.json, as the emulated detector board reads "
                    "it)")] = "ideal"
    ambient: Annotated[float, _m(0.0, 1e15, _NONNEG, _within(0, 1e15), description=(
        "room light on the detector, counts at gain 1 over [detector].integration_time_s (as the signal); "
        "0 = dark room"))] = 0.0
    flicker_depth: Annotated[float, _m(0.0, 1.0, _within(0, 1), description="the room light's modulation at "
                                                                         "flicker_hz (mains lamps: 0.1-1)")] = 0.0
    flicker_hz: Annotated[float, _m(0.0, 1000.0, _within(0, 1000), description="the room light's flicker "
                                                                            "frequency (twice the mains')")] = 100.0
    source_drift_per_h: Annotated[float, _m(-0.9, 10.0, _within(-0.9, 10), description="relative change of the "
                                                                                      "source's power per hour "
                                                                                      "of bench time")] = 0.0
    source_warmup_depth: Annotated[float, _m(0.0, 0.9, _within(0, 0.9), description=(
        "the source's power below nominal at power-up, relative; it rises as 1 - depth exp(-t / "
        "source_warmup_s) over bench time (a lamp warming up)"))] = 0.0
    source_warmup_s: Annotated[float, _m(1e-3, 1e5, _within(1e-3, 1e5), description="the warm-up's time "
                                                                                    "constant")] = 300.0
    monitor_mv: Annotated[float, _m(0.0, 5000.0, _within(0, 5000), description="the monitor photodiode's "
                                                                            "amplifier output (mV) at the "
                                                                            "source's nominal power (firmware "
                                                                            "built with MONITOR=1)")] = 2000.0
    gain_errors: Annotated[list[Annotated[float, Meta(ge=-0.5, le=0.5)]], Meta(description=(
        "the amplifier's real gains' relative errors, by [detector].gains in ascending order (1 % and 5 % "
        "resistors, the multiplexer's leakage); missing ones 0"))] = msgspec.field(default_factory=list)
    backlash_deg: Annotated[float, _m(0.0, 10.0, _NONNEG, _within(0, 10))] = 0.0
    settle_time_s: Annotated[float, _m(0.0, 60.0, _NONNEG, _within(0, 60), description="mechanical settling after a "
                                                                                     "profile ends")] = 0.05
    settle_ringing_deg: Annotated[float, _m(0.0, 10.0, _NONNEG, _within(0, 10))] = 0.0
    stepper_velocity_deg_s: Annotated[float, _m(1e-3, 1e5, _POS, _within(1e-3, 1e5))] = 60.0
    stepper_acceleration_deg_s2: Annotated[float, _m(1e-3, 1e7, _POS, _within(1e-3, 1e7))] = 240.0
    homing_required: Annotated[bool, Meta(description="the stepper controller refuses MOVE until HOME")] = False
    grbl_build: Annotated[Literal["gonio", "stock"], Meta(
        description='the virtual GRBL\'s firmware: "gonio" (firmware/grbl: $H homes X and Y together) or "stock" '
                    "(GRBL 1.1h's release: $H homes Z first, and this bench has no Z switch: ALARM:9)")] = "gonio"
    faults: FaultsSection = msgspec.field(default_factory=FaultsSection)
    spectrometer: SpectrometerSection = msgspec.field(default_factory=SpectrometerSection)
    misalignment: MisalignmentSection = msgspec.field(default_factory=MisalignmentSection)
