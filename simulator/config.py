"""Configuration of the virtual bench, read from the shared TOML file (``configs/simulated.toml``).

Only the sections the simulator needs are interpreted; unknown keys are ignored. Angles in degrees, times in
seconds. The simulator-only keys live in ``[simulator]``, ``[simulator.faults]`` and ``[simulator.spectrometer]``
(all optional, defaults below).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass, field, fields
from pathlib import Path
from typing import Any

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on 3.10 only
    import tomli as tomllib

#: Dynamixel model names -> model numbers (Protocol 2.0 ping reply).
MODEL_NUMBERS = {"XM430-W350": 1020, "XL430-W250": 1060}

#: Default axis letters on the serial text protocol, by axis name.
AXIS_LETTERS = {"light": "L", "detector": "D", "stage": "S"}


@dataclass
class AxisConfig:
    """One rotary axis: ``units = zero_offset + direction * units_per_deg * deg`` (controller units)."""

    name: str
    id: int | str
    model: str = "XM430-W350"
    units_per_deg: float = 4096 / 360
    zero_offset: float = 2048
    direction: int = 1
    min_deg: float = -180.0
    max_deg: float = 180.0
    park_deg: float = 0.0

    @property
    def letter(self) -> str:
        """Axis letter on the serial text protocol (``id`` when it is a string, else L/D/S by name)."""
        if isinstance(self.id, str) and self.id:
            return self.id.upper()
        return AXIS_LETTERS.get(self.name, self.name[:1].upper())

    @property
    def model_number(self) -> int:
        try:
            return MODEL_NUMBERS[self.model]
        except KeyError:
            raise ValueError(f"axis {self.name}: unknown Dynamixel model {self.model!r}") from None

    def deg_to_units(self, deg: float) -> float:
        return self.zero_offset + self.direction * self.units_per_deg * deg

    def units_to_deg(self, units: float) -> float:
        return (units - self.zero_offset) / (self.direction * self.units_per_deg)


@dataclass
class FaultConfig:
    """``[simulator.faults]``: rates are probabilities (per reply packet, per byte, per move, per reading)."""

    drop_reply_rate: float = 0.0       # per status packet / per reply line block
    corrupt_byte_rate: float = 0.0     # per transmitted reply byte
    overload_rate: float = 0.0         # per servo move: overload error during the move
    stall_rate: float = 0.0            # per move: the axis stops partway
    saturate_rate: float = 0.0         # per detector reading (repeat): the reading clips
    port_vanish_after_s: float = 0.0   # simulated seconds; 0 = never
    vanish_ports: str = "all"          # "all" | "dynamixel" | "serial"
    serial_comm_faults: bool = False   # apply drop/corrupt to the serial text port as well
    stall_overload_s: float = 1.0      # a stalled servo raises an overload after this long


@dataclass
class SpectrometerConfig:
    """``[simulator.spectrometer]``: wavelength grid in nm (inclusive range)."""

    wl_min_nm: float = 380.0
    wl_max_nm: float = 780.0
    wl_step_nm: float = 5.0

    def grid(self):
        import numpy as np

        n = int(math.floor((self.wl_max_nm - self.wl_min_nm) / self.wl_step_nm + 1e-9)) + 1
        return self.wl_min_nm + self.wl_step_nm * np.arange(n)


@dataclass
class SimulatorConfig:
    seed: int = 1
    time_scale: float = 0.0
    source_power: float = 1.0e6
    detector_solid_angle_sr: float = 1.0e-3
    aperture_samples: int = 1
    dark_offset: float = 200.0
    read_noise: float = 5.0
    shot_noise: bool = True
    adc_bits: int = 16
    gain: float = 1.0
    backlash_deg: float = 0.0
    settle_time_s: float = 0.05          # servo/stepper mechanical settling after a profile ends
    settle_ringing_deg: float = 0.0      # amplitude of the decaying arm oscillation during settling
    stepper_velocity_deg_s: float = 60.0
    stepper_acceleration_deg_s2: float = 240.0
    homing_required: bool = False        # stepper controller refuses MOVE until HOME when true
    faults: FaultConfig = field(default_factory=FaultConfig)
    spectrometer: SpectrometerConfig = field(default_factory=SpectrometerConfig)


@dataclass
class DetectorConfig:
    type: str = "photodiode"
    integration_time_s: float = 0.01
    repeats: int = 4
    saturation: float = 65535


@dataclass
class MotionConfig:
    profile_velocity: int = 200
    profile_acceleration: int = 50
    tolerance_deg: float = 0.25
    settle_s: float = 0.05


@dataclass
class BenchConfig:
    """Everything the virtual bench needs, plus the raw TOML dict (``raw``) and its directory (``base_dir``)."""

    name: str = "simulated bench"
    motion: str = "dynamixel"
    min_separation_deg: float = 6.0
    blind_spot_half_width_deg: float = 4.0
    axes: dict[str, AxisConfig] = field(default_factory=dict)
    motion_cfg: MotionConfig = field(default_factory=MotionConfig)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    sim: SimulatorConfig = field(default_factory=SimulatorConfig)
    material: dict[str, Any] = field(default_factory=dict)
    reference_reflectance: float = 0.99
    reference_spectrum: str | None = None
    raw: dict[str, Any] = field(default_factory=dict)
    base_dir: Path = field(default_factory=Path.cwd)


def _fill(cls, d: dict[str, Any] | None, **extra):
    d = dict(d or {})
    names = {f.name for f in fields(cls)}
    kwargs = {k: v for k, v in d.items() if k in names and not isinstance(v, dict)}
    kwargs.update(extra)
    return cls(**kwargs)


def _check_keys(section: str, d: dict[str, Any] | None, cls, tables: tuple[str, ...] = ()) -> None:
    known = {f.name for f in fields(cls)} | set(tables)
    unknown = sorted(set(d or {}) - known)
    if unknown:
        raise ValueError(f"config: unknown key(s) {unknown} in [{section}]; known: {sorted(known)}")


def config_from_dict(raw: dict[str, Any], base_dir: Path | None = None) -> BenchConfig:
    """Build a :class:`BenchConfig` from a parsed TOML dict (as from ``tomllib.load``).

    Unknown keys in the simulator's own tables (``[simulator]``, ``[simulator.faults]``,
    ``[simulator.spectrometer]``) are errors (typos would silently disable a fault); other sections belong to
    the whole project and are read leniently.
    """
    bench = raw.get("bench", {})
    axes = {}
    for name, a in raw.get("axes", {}).items():
        if not isinstance(a, dict):
            continue
        axes[name] = _fill(AxisConfig, a, name=name, id=a.get("id", AXIS_LETTERS.get(name, name)))
    for req in ("light", "detector"):
        if req not in axes:
            raise ValueError(f"config: [axes.{req}] is required")
    s = raw.get("simulator", {})
    _check_keys("simulator", s, SimulatorConfig, ("faults", "spectrometer"))
    _check_keys("simulator.faults", s.get("faults"), FaultConfig)
    _check_keys("simulator.spectrometer", s.get("spectrometer"), SpectrometerConfig)
    sim = _fill(
        SimulatorConfig,
        s,
        faults=_fill(FaultConfig, s.get("faults")),
        spectrometer=_fill(SpectrometerConfig, s.get("spectrometer")),
    )
    cal = raw.get("calibration", {})
    ref = cal.get("reference_reflectance", 0.99)
    cfg = BenchConfig(
        name=bench.get("name", "simulated bench"),
        motion=bench.get("motion", "dynamixel"),
        min_separation_deg=float(bench.get("min_separation_deg", 6.0)),
        blind_spot_half_width_deg=float(bench.get("blind_spot_half_width_deg", 4.0)),
        axes=axes,
        motion_cfg=_fill(MotionConfig, raw.get("motion")),
        detector=_fill(DetectorConfig, raw.get("detector")),
        sim=sim,
        material=dict(raw.get("material", {})),
        reference_reflectance=float(ref) if isinstance(ref, (int, float)) else 0.99,
        reference_spectrum=cal.get("reference_spectrum"),
        raw=raw,
        base_dir=Path(base_dir) if base_dir is not None else Path.cwd(),
    )
    if cfg.motion not in ("dynamixel", "serial"):
        raise ValueError(f"config: [bench].motion must be 'dynamixel' or 'serial', not {cfg.motion!r}")
    if cfg.detector.type not in ("photodiode", "spectrometer"):
        raise ValueError(f"config: [detector].type must be 'photodiode' or 'spectrometer', not {cfg.detector.type!r}")
    if cfg.sim.faults.vanish_ports not in ("all", "dynamixel", "serial"):
        raise ValueError("config: [simulator.faults].vanish_ports must be 'all', 'dynamixel' or 'serial'")
    if cfg.sim.time_scale < 0:
        raise ValueError("config: [simulator].time_scale must be >= 0")
    return cfg


def load_config(path: str | Path, **overrides: Any) -> BenchConfig:
    """Load the TOML file at ``path``. ``overrides`` set ``[simulator]`` keys (e.g. ``seed=3, time_scale=0``)."""
    path = Path(path)
    with open(path, "rb") as fh:
        raw = tomllib.load(fh)
    if overrides:
        raw.setdefault("simulator", {})
        for k, v in overrides.items():
            if v is not None:
                raw["simulator"][k] = v
    return config_from_dict(raw, base_dir=path.resolve().parent)
