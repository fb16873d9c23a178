"""Configuration of the virtual bench, read from the shared TOML file (``configs/simulated.toml``).

Only the sections the simulator needs are interpreted, and in those only the keys it reads (type-checked; other
keys are ``gonio-capture``'s). Angles in degrees, times in seconds. The simulator-only keys live in
``[simulator]``, ``[simulator.faults]`` and ``[simulator.spectrometer]`` (all optional, defaults below), which are
validated strictly: unknown keys, wrong types and impossible values are errors (:class:`ConfigError`, whose message
names the file, the table and the key).
"""

from __future__ import annotations

import difflib
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
#: Largest bench file read (bytes), as gonio-capture's limit.
MAX_CONFIG_BYTES = 512 * 1024


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
class BenchConfig:
    """Everything the virtual bench needs, plus the raw TOML dict (``raw``) and its directory (``base_dir``)."""

    name: str = "simulated bench"
    motion: str = "dynamixel"
    min_separation_deg: float = 6.0
    blind_spot_half_width_deg: float = 4.0
    axes: dict[str, AxisConfig] = field(default_factory=dict)
    detector: DetectorConfig = field(default_factory=DetectorConfig)
    sim: SimulatorConfig = field(default_factory=SimulatorConfig)
    material: dict[str, Any] = field(default_factory=dict)
    reference_reflectance: float = 0.99
    reference_spectrum: str | None = None
    raw: dict[str, Any] = field(default_factory=dict)
    base_dir: Path = field(default_factory=Path.cwd)


class ConfigError(ValueError):
    """An invalid simulator config; the message names the file, the table and the key."""


def _describe(v: Any) -> str:
    if isinstance(v, str):
        return f'"{v}"' if len(v) <= 60 else f'"{v[:40]}..." ({len(v)} characters)'
    if isinstance(v, dict):
        return "a table"
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int) and abs(v) >= 10**15:
        return f"{v:.6g}"  # not 300 digits
    if isinstance(v, list) and len(repr(v)) > 80:
        return repr(v)[:60] + f"... ({len(v)} items)"
    return repr(v)


def _convert(kind: str, v: Any) -> tuple[Any, str | None]:
    """A TOML value as ``kind`` (a dataclass field's annotation: float, int, bool, str, int | str); returns
    (value, error text)."""
    is_int = isinstance(v, int) and not isinstance(v, bool)
    if kind == "float":
        if not (is_int or isinstance(v, float)):
            return None, f"expected a number, got {_describe(v)}"
        if not math.isfinite(float(v)):
            return None, f"expected a finite number, got {_describe(v)}"
        return float(v), None
    if kind == "int":
        if is_int:
            return v, None
        if isinstance(v, float) and v.is_integer():
            return int(v), None
        return None, f"expected an integer, got {_describe(v)}"
    if kind == "bool":
        return (v, None) if isinstance(v, bool) else (None, f"expected true or false, got {_describe(v)}")
    if kind == "str":
        return (v, None) if isinstance(v, str) else (None, f"expected a string, got {_describe(v)}")
    if kind == "int | str":
        if is_int or isinstance(v, str):
            return v, None
        return None, f"expected an integer ID or an axis letter, got {_describe(v)}"
    raise AssertionError(kind)  # pragma: no cover - a field type without a reader


#: Range checks of the simulator's own keys: field name -> (test, what it must be).
_NONNEG = (lambda v: v >= 0, "must be >= 0")
_POS = (lambda v: v > 0, "must be > 0")


def _within(lo: float, hi: float) -> tuple[Any, str]:
    return (lambda v: lo <= v <= hi, f"must lie in [{lo:g}, {hi:g}]")


#: Checks of the simulator's own keys, in order: field name -> ((test, what it must be), ...). Beyond the sign,
#: every number is bounded so that no value that passes can make the bench hang, overflow or allocate without
#: bound (a 1e-300 time scale, 1e300 aperture samples, a 1e-9 nm spectrometer step).
_CHECKS: dict[str, tuple[tuple[Any, str], ...]] = {
    **{k: ((lambda v: 0.0 <= v <= 1.0, "must lie in [0, 1]"),)
       for k in ("drop_reply_rate", "corrupt_byte_rate", "overload_rate", "stall_rate", "saturate_rate")},
    "port_vanish_after_s": (_NONNEG,),
    "seed": ((lambda v: 0 <= v < 2**63, "must lie in [0, 2**63)"),),
    "time_scale": (_NONNEG, (lambda v: v == 0 or 1e-3 <= v <= 1e6,
                             "must be 0 (as fast as possible) or lie in [0.001, 1e+06]")),
    "source_power": (_NONNEG, _within(0, 1e15)),
    "detector_solid_angle_sr": (_NONNEG, (lambda v: v <= 2 * math.pi, "must lie in [0, 2 pi] sr")),
    "dark_offset": (_NONNEG, _within(0, 1e9)),
    "read_noise": (_NONNEG, _within(0, 1e9)),
    "backlash_deg": (_NONNEG, _within(0, 10)),
    "settle_ringing_deg": (_NONNEG, _within(0, 10)),
    "settle_time_s": (_NONNEG, _within(0, 60)),
    "stall_overload_s": (_NONNEG, _within(0, 3600)),
    "gain": (_POS, _within(1e-6, 1e6)),
    "stepper_velocity_deg_s": (_POS, _within(1e-3, 1e5)),
    "stepper_acceleration_deg_s2": (_POS, _within(1e-3, 1e7)),
    "wl_min_nm": (_within(100, 3000),),
    "wl_max_nm": (_within(100, 3000),),
    "wl_step_nm": (_POS, _within(0.1, 1000)),
    "aperture_samples": ((lambda v: v >= 1, "must be >= 1"), _within(1, 4096)),
    "adc_bits": ((lambda v: 1 <= v <= 32, "must lie in [1, 32]"),),
    "vanish_ports": ((lambda v: v in ("all", "dynamixel", "serial"), 'must be "all", "dynamixel" or "serial"'),),
}


def _table(src: str, section: str, d: Any) -> dict[str, Any]:
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise ConfigError(f"{src}: [{section}]: expected a table, got {_describe(d)}")
    return d


def _get(src: str, section: str, d: dict[str, Any], key: str, kind: str, default: Any) -> Any:
    """``d[key]`` converted to ``kind`` (``default`` when absent)."""
    if key not in d:
        return default
    v, err = _convert(kind, d[key])
    if err is not None:
        raise ConfigError(f"{src}: [{section}].{key}: {err}")
    return v


def _fill(cls, d: dict[str, Any], src: str, section: str, checks: bool = False, **extra):
    """``cls`` from the table ``d``: every known key type-checked (and range-checked with ``checks``); unknown
    keys are left alone (see :func:`_check_keys`), ``extra`` sets fields directly."""
    kwargs: dict[str, Any] = {}
    for f in fields(cls):
        if f.name in extra or f.name not in d:
            continue
        v, err = _convert(str(f.type), d[f.name])
        if err is None and checks and f.name in _CHECKS:
            for ok, what in _CHECKS[f.name]:
                if not ok(v):
                    err = f"{what}, got {_describe(v)}"
                    break
        if err is not None:
            raise ConfigError(f"{src}: [{section}].{f.name}: {err}")
        kwargs[f.name] = v
    kwargs.update(extra)
    return cls(**kwargs)


def _check_keys(src: str, section: str, d: dict[str, Any], cls, tables: tuple[str, ...] = ()) -> None:
    known = [f.name for f in fields(cls)] + list(tables)
    unknown = [k for k in d if k not in known]
    if unknown:
        near = difflib.get_close_matches(unknown[0], known, n=1)
        hint = f"; did you mean {near[0]!r}?" if near else f"; allowed keys: {', '.join(known)}"
        raise ConfigError(f"{src}: [{section}].{unknown[0]}: unknown key{hint}")


def config_from_dict(raw: dict[str, Any], base_dir: Path | None = None, source: str = "config") -> BenchConfig:
    """Build a :class:`BenchConfig` from a parsed TOML dict (as from ``tomllib.load``); ``source`` names the file
    in error messages.

    The simulator's own tables (``[simulator]``, ``[simulator.faults]``, ``[simulator.spectrometer]``) are read
    strictly: unknown keys (typos would silently disable a fault), wrong types and impossible values are errors.
    Other sections belong to the whole project (``gonio-capture`` validates them): their unknown keys are
    ignored, the keys the simulator reads are type-checked. Errors are :class:`ConfigError` (a ValueError)
    naming ``source``, the table and the key.
    """
    src = source
    bench = _table(src, "bench", raw.get("bench"))
    axes = {}
    for name, a in _table(src, "axes", raw.get("axes")).items():
        if not isinstance(a, dict):
            continue
        ax_id = _get(src, f"axes.{name}", a, "id", "int | str", AXIS_LETTERS.get(name, name))
        axes[name] = _fill(AxisConfig, a, src, f"axes.{name}", name=name, id=ax_id)
    for req in ("light", "detector"):
        if req not in axes:
            raise ConfigError(f"{src}: [axes.{req}]: missing table (required)")
    s = _table(src, "simulator", raw.get("simulator"))
    faults = _table(src, "simulator.faults", s.get("faults"))
    spectrometer = _table(src, "simulator.spectrometer", s.get("spectrometer"))
    _check_keys(src, "simulator", s, SimulatorConfig, ("faults", "spectrometer"))
    _check_keys(src, "simulator.faults", faults, FaultConfig)
    _check_keys(src, "simulator.spectrometer", spectrometer, SpectrometerConfig)
    sim = _fill(
        SimulatorConfig, s, src, "simulator", checks=True,
        faults=_fill(FaultConfig, faults, src, "simulator.faults", checks=True),
        spectrometer=_fill(SpectrometerConfig, spectrometer, src, "simulator.spectrometer", checks=True),
    )
    if sim.spectrometer.wl_max_nm < sim.spectrometer.wl_min_nm:
        raise ConfigError(f"{src}: [simulator.spectrometer].wl_max_nm: {sim.spectrometer.wl_max_nm:g} is less than "
                          f"wl_min_nm {sim.spectrometer.wl_min_nm:g}")
    n_wl = (sim.spectrometer.wl_max_nm - sim.spectrometer.wl_min_nm) / sim.spectrometer.wl_step_nm + 1
    if n_wl > 4096:
        raise ConfigError(f"{src}: [simulator.spectrometer].wl_step_nm: {n_wl:.0f} wavelengths from "
                          f"{sim.spectrometer.wl_min_nm:g} to {sim.spectrometer.wl_max_nm:g} nm, more than a "
                          "spectrometer has (4096); use a coarser step")
    cal = _table(src, "calibration", raw.get("calibration"))
    ref = cal.get("reference_reflectance", 0.99)
    cfg = BenchConfig(
        name=_get(src, "bench", bench, "name", "str", "simulated bench"),
        motion=_get(src, "bench", bench, "motion", "str", "dynamixel"),
        min_separation_deg=_get(src, "bench", bench, "min_separation_deg", "float", 6.0),
        blind_spot_half_width_deg=_get(src, "bench", bench, "blind_spot_half_width_deg", "float", 4.0),
        axes=axes,
        detector=_fill(DetectorConfig, _table(src, "detector", raw.get("detector")), src, "detector"),
        sim=sim,
        material=dict(_table(src, "material", raw.get("material"))),
        reference_reflectance=float(ref) if isinstance(ref, (int, float)) else 0.99,
        reference_spectrum=cal.get("reference_spectrum"),
        raw=raw,
        base_dir=Path(base_dir) if base_dir is not None else Path.cwd(),
    )
    if cfg.motion not in ("dynamixel", "serial"):
        raise ConfigError(f"{src}: [bench].motion: must be \"dynamixel\" or \"serial\", got {_describe(cfg.motion)}")
    if cfg.detector.type not in ("photodiode", "spectrometer"):
        raise ConfigError(f"{src}: [detector].type: must be \"photodiode\" or \"spectrometer\", got "
                          f"{_describe(cfg.detector.type)}")
    return cfg


def load_config(path: str | Path, **overrides: Any) -> BenchConfig:
    """Load the TOML file at ``path``. ``overrides`` set ``[simulator]`` keys (e.g. ``seed=3, time_scale=0``).

    Raises :class:`ConfigError` (a ValueError) naming the file for a missing, unreadable or malformed file."""
    path = Path(path)
    try:
        if path.exists() and not path.is_dir() and not path.is_file():
            raise ConfigError(f"{path}: not a regular file (a device or a pipe), expected a TOML bench file")
        with open(path, "rb") as fh:
            data = fh.read(MAX_CONFIG_BYTES + 1)
        if len(data) > MAX_CONFIG_BYTES:
            raise ConfigError(f"{path}: larger than {MAX_CONFIG_BYTES} bytes; not a bench file")
        raw = tomllib.loads(data.decode("utf-8-sig"))
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except IsADirectoryError:
        raise ConfigError(f"{path}: is a directory, expected a TOML bench file") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read: {e.strerror or e}") from None
    except UnicodeDecodeError as e:
        raise ConfigError(f"{path}: not a UTF-8 text file ({e.reason} at byte {e.start})") from None
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: invalid TOML: {e}") from None
    except RecursionError:
        raise ConfigError(f"{path}: invalid TOML: nested too deeply") from None
    if overrides:
        sim = raw.setdefault("simulator", {})
        if isinstance(sim, dict):
            for k, v in overrides.items():
                if v is not None:
                    sim[k] = v
    return config_from_dict(raw, base_dir=path.resolve().parent, source=str(path))
