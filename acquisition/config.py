"""Bench configuration: load a TOML bench file and validate every key before anything moves.

A bench file has the sections ``[bench]``, ``[axes.light]``, ``[axes.detector]`` (and optional
``[axes.stage]``), ``[motion]``, ``[detector]``, ``[calibration]`` and ``[plan]`` (see ``configs/*.toml``, whose
comments document each key). ``[material]`` (the simulated sample) is validated with
``reconstruction.models.Material.from_dict``; ``[simulator]`` and its sub-tables belong to ``gonio-sim``,
which validates them (``gonio-sim check``, run by ``gonio-capture --check``; ``gonio-sim serve`` refuses a bad
file with exit status 2 when a capture starts it); here they only have to be tables. Any other section or key is
an error.

Every error is a :class:`~acquisition.errors.ConfigError` whose message names the file and the key, e.g.
``configs/x.toml: [axes.light].max_deg: expected a number, got "high"``. Angles in degrees, times in
seconds.
"""

from __future__ import annotations

import csv
import difflib
import logging
import math
import stat
import sys
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from .errors import ConfigError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 only
    import tomli as tomllib

__all__ = [
    "AxisConfig",
    "BenchSection",
    "MotionConfig",
    "DetectorConfig",
    "CalibrationConfig",
    "AdaptiveConfig",
    "PlanConfig",
    "BenchConfig",
    "load_config",
    "config_from_dict",
    "DXL_MODELS",
    "DXL_BAUDRATES",
    "MAX_PLAN_POINTS",
    "resolution_deg",
]

#: Dynamixel model names accepted in ``[axes.*].model`` -> model number answered to a ping.
DXL_MODELS = {"XM430-W350": 1020, "XL430-W250": 1060}
#: Baud rates the Dynamixel SDK's PortHandler accepts.
DXL_BAUDRATES = (9600, 19200, 38400, 57600, 115200, 230400, 460800, 500000, 576000, 921600, 1000000, 1152000,
                 2000000, 2500000, 3000000, 3500000, 4000000)
#: Default axis letters on the serial text protocol, by axis name.
AXIS_LETTERS = {"light": "L", "detector": "D", "stage": "S"}
TRANSPORTS = ("dynamixel", "serial", "simulated")
DXL_POSITION_RANGE = (0, 4095)  # position mode (operating mode 3), one turn
#: Integration times the detector protocol accepts (``INT <s>``, docs/serial-protocol.md), seconds.
MIN_INTEGRATION_TIME_S, MAX_INTEGRATION_TIME_S = 1e-5, 10.0

_TOP_SECTIONS = ("bench", "axes", "motion", "detector", "calibration", "plan", "material", "simulator")

#: A plan may hold at most this many points (incidences x outgoing angles, or the adaptive refinement's worst
#: case): bigger plans are a config error, not a capture of days. That is more than a full 1 x 1 degree in-plane
#: grid (86 x 177 points), about 6 hours at 1 s per point on a real bench; ``gonio-capture --check`` prints the
#: size and estimated time of any plan within it in under a second.
MAX_PLAN_POINTS = 20_000
#: Largest bench file read (bytes): a bench file is a few kilobytes (an explicit list of MAX_PLAN_POINTS points
#: fits); anything larger is not one, and would take seconds to parse.
MAX_CONFIG_BYTES = 512 * 1024
#: Largest controller position a serial-protocol axis may be sent (the controller's int32 step counter).
MAX_SERIAL_UNITS = 2**31 - 1
#: Largest |f_r| (1/sr) a simulated [material] may reach anywhere (the bound the reconstruction accepts too).
MAX_MATERIAL_BRDF = 1e8
#: Most wavelengths a [material] spectrum may have.
MAX_MATERIAL_CHANNELS = 4096

log = logging.getLogger("acquisition.config")


# --- typed, strict reading of one table ----------------------------------------------------------------------


class _F:
    """Field spec: ``kind`` is "str", "int", "float", "bool", "list[float]", "points" or "str|int"."""

    def __init__(self, kind: str, required: bool = False, default: Any = None,
                 check: Callable[[Any], str | None] | None = None, choices: Sequence[Any] | None = None) -> None:
        self.kind = kind
        self.required = required
        self.default = default
        self.check = check
        self.choices = choices


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


def _is_num(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def _convert(kind: str, v: Any) -> tuple[Any, str | None]:
    """Convert a TOML value to ``kind``; returns (value, error text)."""
    if kind == "str":
        return (v, None) if isinstance(v, str) else (None, f"expected a string, got {_describe(v)}")
    if kind == "bool":
        return (v, None) if isinstance(v, bool) else (None, f"expected true or false, got {_describe(v)}")
    if kind == "int":
        if isinstance(v, int) and not isinstance(v, bool):
            return v, None
        if isinstance(v, float) and v.is_integer():
            return int(v), None
        return None, f"expected an integer, got {_describe(v)}"
    if kind == "float":
        if not _is_num(v):
            return None, f"expected a number, got {_describe(v)}"
        if not math.isfinite(float(v)):
            return None, f"expected a finite number, got {_describe(v)}"
        return float(v), None
    if kind == "str|int":
        if isinstance(v, str) or (isinstance(v, int) and not isinstance(v, bool)):
            return v, None
        return None, f"expected an integer ID or an axis letter, got {_describe(v)}"
    if kind == "list[float]":
        if not isinstance(v, list) or not v:
            return None, f"expected a non-empty list of numbers, got {_describe(v)}"
        if not all(_is_num(x) and math.isfinite(float(x)) for x in v):
            return None, f"expected a list of numbers, got {_describe(v)}"
        return [float(x) for x in v], None
    if kind == "points":
        if not isinstance(v, list) or not v:
            return None, f"expected a non-empty list of [theta_i_deg, theta_o_deg] pairs, got {_describe(v)}"
        out = []
        for p in v:
            if not (isinstance(p, list) and len(p) == 2 and all(_is_num(x) and math.isfinite(float(x)) for x in p)):
                return None, f"expected [theta_i_deg, theta_o_deg] pairs, got {_describe(p)}"
            out.append((float(p[0]), float(p[1])))
        return out, None
    raise AssertionError(kind)  # pragma: no cover


class _Table:
    """Reads one TOML table against a spec; every error names ``file: [section].key``."""

    def __init__(self, source: str, section: str, raw: Any, spec: Mapping[str, _F]) -> None:
        self.source = source
        self.section = section
        if not isinstance(raw, Mapping):
            raise ConfigError(f"{source}: [{section}]: expected a table, got {_describe(raw)}")
        self.raw = dict(raw)
        self.spec = spec
        unknown = [k for k in self.raw if k not in spec]
        if unknown:
            k = unknown[0]
            near = difflib.get_close_matches(k, list(spec), n=1)
            hint = f"; did you mean {near[0]!r}?" if near else f"; allowed keys: {', '.join(spec)}"
            raise ConfigError(f"{source}: [{section}].{k}: unknown key{hint}")
        self.values: dict[str, Any] = {}
        for k, f in spec.items():
            if k not in self.raw:
                if f.required:
                    raise ConfigError(f"{source}: [{section}].{k}: missing key (required)")
                self.values[k] = f.default
                continue
            v, err = _convert(f.kind, self.raw[k])
            if err is None and f.choices is not None and v not in f.choices:
                err = f"expected one of {', '.join(map(_describe, f.choices))}, got {_describe(v)}"
            if err is None and f.check is not None:
                err = f.check(v)
            if err is not None:
                raise ConfigError(f"{source}: [{section}].{k}: {err}")
            self.values[k] = v

    def __getitem__(self, key: str) -> Any:
        return self.values[key]

    def given(self, key: str) -> bool:
        return key in self.raw

    def error(self, key: str, text: str) -> ConfigError:
        return ConfigError(f"{self.source}: [{self.section}].{key}: {text}")


def _pos(v: float) -> str | None:
    return None if v > 0 else f"must be > 0, got {v:g}"


def _nonneg(v: float) -> str | None:
    return None if v >= 0 else f"must be >= 0, got {v:g}"


def _range(lo: float, hi: float) -> Callable[[float], str | None]:
    def check(v: float) -> str | None:
        return None if lo <= v <= hi else f"must lie in [{lo:g}, {hi:g}], got {v:g}"
    return check


# --- config dataclasses ----------------------------------------------------------------------------------------


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


@dataclass(frozen=True)
class DetectorConfig:
    """``[detector]``: type, integration time per repeat (s), default repeats, saturation (raw counts), dark
    repeats, and auto-ranging: with ``auto_range`` a saturated reading is taken again at shorter integration
    times, down to ``min_integration_time_s`` (s), and converted back to ``integration_time_s``."""

    type: str
    integration_time_s: float
    repeats: int
    saturation: float
    dark_repeats: int
    auto_range: bool = True
    min_integration_time_s: float = 1e-5


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


@dataclass(frozen=True)
class AdaptiveConfig:
    """``[plan.adaptive]``: coarse pass at ``coarse_step_deg``, then midpoints where the slice changes fast."""

    enabled: bool
    coarse_step_deg: float
    min_step_deg: float
    tolerance: float
    time_budget_s: float
    max_points: int
    max_rounds: int


@dataclass(frozen=True)
class PlanConfig:
    """``[plan]``: incidence angles, outgoing range and step, repeats, options."""

    theta_i_deg: tuple[float, ...]
    theta_o_min_deg: float | None
    theta_o_max_deg: float | None
    theta_o_step_deg: float | None
    points: tuple[tuple[float, float], ...] | None
    repeats: int
    dark_at_end: bool
    order: str
    strict: bool
    scene: str | None
    sample_name: str | None
    adaptive: AdaptiveConfig | None


@dataclass
class BenchConfig:
    """A validated bench file. ``raw`` is the parsed TOML, ``path`` the file, ``base_dir`` its directory."""

    path: Path
    bench: BenchSection
    axes: dict[str, AxisConfig]
    motion: MotionConfig
    detector: DetectorConfig
    calibration: CalibrationConfig
    plan: PlanConfig
    material: dict[str, Any] | None
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def base_dir(self) -> Path:
        return self.path.resolve().parent

    @property
    def light(self) -> AxisConfig:
        return self.axes["light"]

    @property
    def det_axis(self) -> AxisConfig:
        return self.axes["detector"]

    @property
    def sample_name(self) -> str | None:
        if self.plan.sample_name:
            return self.plan.sample_name
        if self.material is not None:
            return str(self.material.get("name", "material"))
        return None


# --- section readers -----------------------------------------------------------------------------------------


def _read_bench(src: str, raw: Any) -> BenchSection:
    t = _Table(src, "bench", raw, {
        "name": _F("str", default="bench"),
        "transport": _F("str", required=True, choices=TRANSPORTS),
        "motion": _F("str", choices=("dynamixel", "serial")),
        "dynamixel_port": _F("str", default=""),
        "dynamixel_baudrate": _F("int", default=1000000, choices=DXL_BAUDRATES),
        "serial_port": _F("str", default=""),
        "serial_baudrate": _F("int", default=115200, check=lambda v: _pos(v) or _range(50, 1e8)(v)),
        "serial_timeout_s": _F("float", default=1.0, check=lambda v: _pos(v) or _range(1e-3, 60)(v)),
        "min_separation_deg": _F("float", required=True, check=_range(0, 90)),
        "blind_spot_half_width_deg": _F("float", required=True, check=_range(0, 90)),
        "simulator_command": _F("str", default="gonio-sim"),
    })
    transport = t["transport"]
    motion = t["motion"]
    if transport == "simulated":
        if motion is None:
            raise t.error("motion", 'missing key: a simulated bench needs motion = "dynamixel" or "serial"')
    else:
        if motion is not None and motion != transport:
            raise t.error("motion", f'is {_describe(motion)} but transport is "{transport}"; leave motion out '
                                    "or make them equal (motion is for simulated benches)")
        motion = transport
        if transport == "dynamixel" and not t["dynamixel_port"]:
            raise t.error("dynamixel_port", "missing: a Dynamixel bench needs the servo bus port, e.g. "
                                            '"/dev/ttyUSB0"')
        if not t["serial_port"]:
            raise t.error("serial_port", "missing: the serial controller (detector"
                                         + (" and stepper axes" if transport == "serial" else "")
                                         + ') needs a port, e.g. "/dev/ttyACM0"')
    return BenchSection(t["name"], transport, motion, t["dynamixel_port"], t["dynamixel_baudrate"],
                        t["serial_port"], t["serial_baudrate"], t["serial_timeout_s"], t["min_separation_deg"],
                        t["blind_spot_half_width_deg"], t["simulator_command"])


def _read_axis(src: str, name: str, raw: Any, motion: str) -> AxisConfig:
    sec = f"axes.{name}"
    t = _Table(src, sec, raw, {
        "id": _F("str|int", required=True),
        "model": _F("str"),
        "units_per_deg": _F("float", required=True,
                            check=lambda v: _pos(v) or (None if 1e-2 <= v <= 1e6 else
                                                        f"must lie in [0.01, 1e+06] units per degree, got {v:g}")),
        "zero_offset": _F("float", required=True,
                          check=lambda v: None if abs(v) <= 1e9 else f"must lie in [-1e+09, 1e+09], got {v:g}"),
        "direction": _F("int", required=True, choices=(1, -1)),
        "min_deg": _F("float", required=True, check=_range(-180, 180)),
        "max_deg": _F("float", required=True, check=_range(-180, 180)),
        "park_deg": _F("float", required=True, check=_range(-180, 180)),
    })
    ax_id = t["id"]
    if motion == "dynamixel":
        if not isinstance(ax_id, int) or not 0 <= ax_id <= 252:
            raise t.error("id", f"expected a Dynamixel ID 0..252 on a Dynamixel bench, got {_describe(ax_id)}")
        if t["model"] is None:
            raise t.error("model", f"missing key: the Dynamixel model, one of {', '.join(DXL_MODELS)}")
        if t["model"] not in DXL_MODELS:
            raise t.error("model", f"unknown Dynamixel model {_describe(t['model'])}; known: "
                                   f"{', '.join(DXL_MODELS)}")
    else:
        if isinstance(ax_id, str) and not (len(ax_id) == 1 and ax_id.isalpha()):
            raise t.error("id", f"expected one axis letter (e.g. \"L\") on the serial controller, got "
                                f"{_describe(ax_id)}")
        if isinstance(ax_id, int) and ax_id < 0:
            raise t.error("id", f"must be >= 0, got {ax_id}")
    lo, hi = t["min_deg"], t["max_deg"]
    if not lo < hi:
        raise t.error("max_deg", f"must be greater than min_deg ({lo:g}), got {hi:g}")
    if name in ("light", "detector") and (lo < -90 or hi > 90):
        key = "min_deg" if lo < -90 else "max_deg"
        raise t.error(key, f"the {name} arm must stay within [-90, 90] degrees of the normal, got {t[key]:g}")
    if not lo <= t["park_deg"] <= hi:
        raise t.error("park_deg", f"{t['park_deg']:g} is outside the soft limits [{lo:g}, {hi:g}] (min_deg, max_deg)")
    ax = AxisConfig(name, ax_id, t["model"], t["units_per_deg"], t["zero_offset"], t["direction"], lo, hi,
                    t["park_deg"])
    u = sorted((ax.deg_to_units(lo), ax.deg_to_units(hi)))
    if motion == "dynamixel":
        if u[0] < DXL_POSITION_RANGE[0] - 0.5 or u[1] > DXL_POSITION_RANGE[1] + 0.5:
            raise t.error("zero_offset", f"the soft limits [{lo:g}, {hi:g}] deg map to positions "
                                         f"[{u[0]:.6g}, {u[1]:.6g}], outside the servo's one-turn range 0..4095 "
                                         f"(position mode); change zero_offset or the limits (units_per_deg = "
                                         f"{ax.units_per_deg:g})")
    elif max(abs(u[0]), abs(u[1])) > MAX_SERIAL_UNITS:
        key = "zero_offset" if abs(ax.zero_offset) > MAX_SERIAL_UNITS / 2 else "units_per_deg"
        raise t.error(key, f"the soft limits [{lo:g}, {hi:g}] deg map to controller positions [{u[0]:.6g}, "
                           f"{u[1]:.6g}], beyond the controller's step counter (+-{MAX_SERIAL_UNITS}); check "
                           f"units_per_deg ({ax.units_per_deg:g}) and zero_offset ({ax.zero_offset:g})")
    return ax


def _read_motion(src: str, raw: Any, motion: str) -> MotionConfig:
    t = _Table(src, "motion", raw, {
        "profile_velocity": _F("int", default=None, check=_range(0, 32767)),
        "profile_acceleration": _F("int", default=None, check=_range(0, 32767)),
        "velocity_deg_s": _F("float", default=60.0, check=lambda v: _pos(v) or _range(1e-3, 1e5)(v)),
        "acceleration_deg_s2": _F("float", default=240.0, check=lambda v: _pos(v) or _range(1e-3, 1e7)(v)),
        "tolerance_deg": _F("float", required=True, check=_pos),
        "settle_s": _F("float", required=True, check=_range(0, 60)),
        "timeout_s": _F("float", default=20.0, check=lambda v: _pos(v) or _range(1e-3, 3600)(v)),
        "retries": _F("int", default=3, check=_range(0, 100)),
        "poll_interval_s": _F("float", default=0.01, check=_range(0, 10)),
    })
    if motion == "dynamixel":
        for k in ("profile_velocity", "profile_acceleration"):
            if t[k] is None:
                raise t.error(k, "missing key: a Dynamixel bench needs the profile (0 = unlimited)")
    if t["tolerance_deg"] > 5:
        raise t.error("tolerance_deg", f"{t['tolerance_deg']:g} deg is not a position tolerance (max 5)")
    return MotionConfig(t["profile_velocity"] or 0, t["profile_acceleration"] or 0, t["velocity_deg_s"],
                        t["acceleration_deg_s2"], t["tolerance_deg"], t["settle_s"], t["timeout_s"], t["retries"],
                        t["poll_interval_s"])


def _read_detector(src: str, raw: Any) -> DetectorConfig:
    t = _Table(src, "detector", raw, {
        "type": _F("str", required=True, choices=("photodiode", "spectrometer")),
        "integration_time_s": _F("float", required=True,
                                 check=_range(MIN_INTEGRATION_TIME_S, MAX_INTEGRATION_TIME_S)),
        "repeats": _F("int", required=True, check=_range(1, 1000)),
        "saturation": _F("float", required=True, check=lambda v: _pos(v) or _range(1, 2.0**32)(v)),
        "dark_repeats": _F("int", default=32, check=_range(1, 1000)),
        "auto_range": _F("bool", default=True),
        "min_integration_time_s": _F("float", default=MIN_INTEGRATION_TIME_S,
                                     check=_range(MIN_INTEGRATION_TIME_S, MAX_INTEGRATION_TIME_S)),
    })
    if t["min_integration_time_s"] > t["integration_time_s"]:
        raise t.error("min_integration_time_s", f"{t['min_integration_time_s']:g} s is longer than "
                                                f"integration_time_s = {t['integration_time_s']:g} s")
    return DetectorConfig(t["type"], t["integration_time_s"], t["repeats"], t["saturation"], t["dark_repeats"],
                          t["auto_range"], t["min_integration_time_s"])


def read_spectrum_csv(path: Path, where: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Read a ``wavelength_nm,reflectance`` CSV (a header line and ``#`` comments allowed)."""
    wl: list[float] = []
    val: list[float] = []
    try:
        text = _open_text(path, "a wavelength_nm,reflectance CSV file")
    except ConfigError as e:
        raise ConfigError(f"{where}: cannot read {e}") from None
    for lineno, line in enumerate(text.splitlines(), 1):
        try:
            row = next(csv.reader([line]), [])
        except csv.Error as e:
            raise ConfigError(f"{where}: {path}:{lineno}: {e}") from None
        if not row or not row[0].strip() or row[0].strip().startswith("#"):
            continue
        try:
            w, v = float(row[0]), float(row[1])
        except (ValueError, IndexError):
            if not wl and lineno == 1:
                continue  # header
            raise ConfigError(f"{where}: {path}:{lineno}: expected wavelength_nm,reflectance numbers, "
                              f"got {','.join(row)[:60]!r}") from None
        if not (math.isfinite(w) and math.isfinite(v) and 0 < v <= 1.5):
            raise ConfigError(f"{where}: {path}:{lineno}: reflectance must lie in (0, 1.5], got {v:g}")
        if not 100.0 <= w <= 3000.0:
            raise ConfigError(f"{where}: {path}:{lineno}: wavelength must lie in [100, 3000] nm, got {w:g}")
        if wl and w <= wl[-1]:
            raise ConfigError(f"{where}: {path}:{lineno}: wavelengths must increase")
        wl.append(w)
        val.append(v)
    if len(wl) < 2:
        raise ConfigError(f"{where}: {path}: needs at least two wavelength_nm,reflectance rows")
    return tuple(wl), tuple(val)


def _read_calibration(src: str, raw: Any, base_dir: Path) -> CalibrationConfig:
    t = _Table(src, "calibration", raw, {
        "mode": _F("str", required=True, choices=("relative", "absolute")),
        "reference_reflectance": _F("float", check=lambda v: None if 0 < v <= 1.5
                                    else f"must lie in (0, 1.5], got {v:g}"),
        "reference_spectrum": _F("str"),
        "reference_theta_i_deg": _F("float", check=_range(-89.9, 89.9)),
        "reference_theta_o_deg": _F("float", check=_range(-89.9, 89.9)),
        "reference_repeats": _F("int", default=32, check=_range(1, 1000)),
        "source_power": _F("float", check=lambda v: _pos(v) or _range(1e-6, 1e18)(v)),
        "detector_solid_angle_sr": _F("float", check=lambda v: _pos(v) or _range(1e-12, 2 * math.pi)(v)),
    })
    mode = t["mode"]
    spectrum = None
    if t["reference_spectrum"] is not None:
        p = Path(t["reference_spectrum"])
        if not p.is_absolute():
            p = base_dir / p
        spectrum = read_spectrum_csv(p, f"{src}: [calibration].reference_spectrum")
    if mode == "relative":
        if t["reference_reflectance"] is None and spectrum is None:
            raise t.error("reference_reflectance", "missing: relative calibration needs reference_reflectance "
                                                   "(a number) or reference_spectrum (a CSV file)")
        if t.given("reference_reflectance") and t.given("reference_spectrum"):
            raise t.error("reference_spectrum", "give either reference_reflectance or reference_spectrum, "
                                                "not both")
        for k in ("reference_theta_i_deg", "reference_theta_o_deg"):
            if t[k] is None:
                raise t.error(k, "missing key: the reference geometry of the white reference")
    else:
        for k in ("source_power", "detector_solid_angle_sr"):
            if t[k] is None:
                raise t.error(k, "missing key: absolute calibration needs source_power (counts per "
                                 "1/sr * sr at the configured integration time) and detector_solid_angle_sr")
    return CalibrationConfig(mode, t["reference_reflectance"], spectrum, t["reference_spectrum"],
                             t["reference_theta_i_deg"] if t["reference_theta_i_deg"] is not None else 0.0,
                             t["reference_theta_o_deg"] if t["reference_theta_o_deg"] is not None else 10.0,
                             t["reference_repeats"], t["source_power"], t["detector_solid_angle_sr"])


def resolution_deg(ax: AxisConfig) -> float:
    """The smallest angle step (deg) an axis can make: one controller unit."""
    return 1.0 / ax.units_per_deg


def _count(lo: float, hi: float, step: float) -> float:
    """Number of angles ``lo, lo + step, ... <= hi`` plus the end (as :func:`_frange` and the plan make them),
    computed without building them (a float: may be astronomically large)."""
    return math.floor((hi - lo) / step + 1e-9) + 2.0


def _finer_than_axis(src: str, section: str, key: str, step: float, ax: AxisConfig) -> None:
    res = resolution_deg(ax)
    if step < res * (1 - 1e-9):
        raise ConfigError(f"{src}: [{section}].{key}: {step:g} deg is finer than the {ax.name} axis resolution of "
                          f"{res:.4g} deg (1 / [axes.{ax.name}].units_per_deg = 1 / {ax.units_per_deg:g}); no "
                          "position between two controller units can be reached")


def _read_adaptive(src: str, raw: Any, step: float | None) -> AdaptiveConfig:
    t = _Table(src, "plan.adaptive", raw, {
        "enabled": _F("bool", default=True),
        "coarse_step_deg": _F("float", check=_pos),
        "min_step_deg": _F("float", default=0.5, check=_pos),
        "tolerance": _F("float", default=0.05, check=_pos),
        "time_budget_s": _F("float", default=0.0, check=_nonneg),
        "max_points": _F("int", default=0, check=_nonneg),
        "max_rounds": _F("int", default=6, check=_range(1, 50)),
    })
    coarse = t["coarse_step_deg"] if t["coarse_step_deg"] is not None else (4 * step if step else None)
    if coarse is None:
        raise t.error("coarse_step_deg", "missing key (no theta_o_step_deg to derive it from)")
    if t["min_step_deg"] > coarse:
        raise t.error("min_step_deg", f"{t['min_step_deg']:g} is larger than coarse_step_deg {coarse:g}")
    return AdaptiveConfig(t["enabled"], coarse, t["min_step_deg"], t["tolerance"], t["time_budget_s"],
                          t["max_points"], t["max_rounds"])


def _read_plan(src: str, raw: Any, det: DetectorConfig, axes: Mapping[str, AxisConfig]) -> PlanConfig:
    raw = dict(raw) if isinstance(raw, Mapping) else raw
    adaptive_raw = raw.pop("adaptive", None) if isinstance(raw, dict) else None
    t = _Table(src, "plan", raw, {
        "theta_i_deg": _F("list[float]"),
        "theta_i_min_deg": _F("float"),
        "theta_i_max_deg": _F("float"),
        "theta_i_step_deg": _F("float", check=_pos),
        "theta_o_min_deg": _F("float", check=_range(-90, 90)),
        "theta_o_max_deg": _F("float", check=_range(-90, 90)),
        "theta_o_step_deg": _F("float", check=_pos),
        "points": _F("points"),
        "repeats": _F("int", default=det.repeats, check=_range(1, 1000)),
        "dark_at_end": _F("bool", default=True),
        "order": _F("str", default="optimized", choices=("optimized", "naive")),
        "strict": _F("bool", default=False),
        "scene": _F("str"),
        "sample_name": _F("str"),
    })
    ti: list[float] = []
    if t["theta_i_deg"] is not None:
        if any(t.given(k) for k in ("theta_i_min_deg", "theta_i_max_deg", "theta_i_step_deg")):
            raise t.error("theta_i_min_deg", "give either theta_i_deg (a list) or theta_i_min_deg/max/step, "
                                             "not both")
        ti = t["theta_i_deg"]
    elif any(t.given(k) for k in ("theta_i_min_deg", "theta_i_max_deg", "theta_i_step_deg")):
        for k in ("theta_i_min_deg", "theta_i_max_deg", "theta_i_step_deg"):
            if t[k] is None:
                raise t.error(k, "missing key (theta_i_min_deg, theta_i_max_deg and theta_i_step_deg go "
                                 "together)")
        if t["theta_i_max_deg"] < t["theta_i_min_deg"]:
            raise t.error("theta_i_max_deg", "must be >= theta_i_min_deg")
        _finer_than_axis(src, "plan", "theta_i_step_deg", t["theta_i_step_deg"], axes["light"])
        n = _count(t["theta_i_min_deg"], t["theta_i_max_deg"], t["theta_i_step_deg"])
        if n > MAX_PLAN_POINTS:
            raise t.error("theta_i_step_deg", f"{n:.3g} incidences, more than a plan may hold "
                                              f"({MAX_PLAN_POINTS} points); use a coarser step")
        ti = _frange(t["theta_i_min_deg"], t["theta_i_max_deg"], t["theta_i_step_deg"])
    for x in ti:
        if not -90 < x < 90:
            raise t.error("theta_i_deg", f"incidence {x:g} is outside (-90, 90) degrees")
    has_range = any(t.given(k) for k in ("theta_o_min_deg", "theta_o_max_deg", "theta_o_step_deg"))
    if t["points"] is None:
        if not ti:
            raise t.error("theta_i_deg", "missing key: the incidence angles (or an explicit points list)")
        for k in ("theta_o_min_deg", "theta_o_max_deg", "theta_o_step_deg"):
            if t[k] is None:
                raise t.error(k, "missing key: the outgoing range and step")
        if t["theta_o_max_deg"] < t["theta_o_min_deg"]:
            raise t.error("theta_o_max_deg", f"{t['theta_o_max_deg']:g} is less than theta_o_min_deg "
                                             f"{t['theta_o_min_deg']:g}")
        _finer_than_axis(src, "plan", "theta_o_step_deg", t["theta_o_step_deg"], axes["detector"])
        n = len(ti) * _count(t["theta_o_min_deg"], t["theta_o_max_deg"], t["theta_o_step_deg"])
        if n > MAX_PLAN_POINTS:
            raise t.error("theta_o_step_deg", f"the plan would have {n:.3g} points ({len(ti)} incidence(s) x "
                                              f"{n / len(ti):.3g} outgoing angles), more than the {MAX_PLAN_POINTS} "
                                              "a plan may hold; use a coarser step or fewer incidences")
    elif ti or has_range:
        raise t.error("points", "give either an explicit points list or theta_i_deg with a theta_o range, "
                                "not both")
    if t["points"] is not None and len(t["points"]) > MAX_PLAN_POINTS:
        raise t.error("points", f"{len(t['points'])} points, more than the {MAX_PLAN_POINTS} a plan may hold")
    adaptive = None
    if adaptive_raw is not None:
        adaptive = _read_adaptive(src, adaptive_raw, t["theta_o_step_deg"])
        for key in ("coarse_step_deg", "min_step_deg"):
            if adaptive.enabled:
                _finer_than_axis(src, "plan.adaptive", key, getattr(adaptive, key), axes["detector"])
        if ti and t["theta_o_min_deg"] is not None and adaptive.enabled:
            worst = len(ti) * _count(t["theta_o_min_deg"], t["theta_o_max_deg"], adaptive.min_step_deg)
            if worst > MAX_PLAN_POINTS and not 0 < adaptive.max_points <= MAX_PLAN_POINTS:
                raise ConfigError(f"{src}: [plan.adaptive].min_step_deg: the refinement could reach {worst:.3g} "
                                  f"points ({len(ti)} incidence(s) at {adaptive.min_step_deg:g} deg), more than the "
                                  f"{MAX_PLAN_POINTS} a plan may hold; set max_points (at most {MAX_PLAN_POINTS}) "
                                  "or a coarser min_step_deg")
        if t["points"] is not None and adaptive.enabled:
            raise ConfigError(f"{src}: [plan.adaptive].enabled: adaptive refinement needs a theta_o range, "
                              "not an explicit points list")
        if not adaptive.enabled:
            adaptive = None
    return PlanConfig(tuple(ti), t["theta_o_min_deg"], t["theta_o_max_deg"], t["theta_o_step_deg"],
                      tuple(t["points"]) if t["points"] is not None else None, t["repeats"], t["dark_at_end"],
                      t["order"], t["strict"], t["scene"], t["sample_name"], adaptive)


def _frange(lo: float, hi: float, step: float) -> list[float]:
    """``lo, lo + step, ... <= hi`` (inclusive within 1e-9), rounded to 1e-9 deg."""
    n = int(math.floor((hi - lo) / step + 1e-9))
    return [round(lo + k * step, 9) for k in range(n + 1)]


# --- whole file --------------------------------------------------------------------------------------------------


def config_from_dict(raw: Mapping[str, Any], path: str | Path = "<config>") -> BenchConfig:
    """Validate a parsed bench file (as from ``tomllib.load``); ``path`` names it in errors and anchors relative
    paths."""
    path = Path(path)
    src = str(path)
    raw = dict(raw)
    unknown = [k for k in raw if k not in _TOP_SECTIONS]
    if unknown:
        near = difflib.get_close_matches(unknown[0], _TOP_SECTIONS, n=1)
        hint = f"; did you mean [{near[0]}]?" if near else f"; allowed sections: {', '.join(_TOP_SECTIONS)}"
        raise ConfigError(f"{src}: [{unknown[0]}]: unknown section{hint}")
    for sec in ("bench", "axes", "motion", "detector", "calibration", "plan"):
        if sec not in raw:
            raise ConfigError(f"{src}: [{sec}]: missing section (required)")
    bench = _read_bench(src, raw["bench"])
    axes_raw = raw["axes"]
    if not isinstance(axes_raw, Mapping):
        raise ConfigError(f"{src}: [axes]: expected tables [axes.light], [axes.detector]")
    for name in axes_raw:
        if name not in ("light", "detector", "stage"):
            raise ConfigError(f"{src}: [axes.{name}]: unknown axis; allowed: light, detector, stage")
    for name in ("light", "detector"):
        if name not in axes_raw:
            raise ConfigError(f"{src}: [axes.{name}]: missing section (required)")
    axes = {name: _read_axis(src, name, axes_raw[name], bench.motion) for name in axes_raw}
    seen: dict[Any, str] = {}
    for name, a in axes.items():
        key = a.id if bench.motion == "dynamixel" else a.letter
        if key in seen:
            raise ConfigError(f"{src}: [axes.{name}].id: {_describe(key)} is already the id of [axes.{seen[key]}]"
                              "; every axis needs its own")
        seen[key] = name
    motion = _read_motion(src, raw["motion"], bench.motion)
    detector = _read_detector(src, raw["detector"])
    calibration = _read_calibration(src, raw["calibration"], path.resolve().parent)
    plan = _read_plan(src, raw["plan"], detector, axes)
    material = None
    if "material" in raw:
        from reconstruction.models import Material, MaterialError

        try:
            mat = Material.from_dict(raw["material"], path.resolve().parent, source=f"{src}: [material]")
        except MaterialError as e:
            raise ConfigError(str(e)) from None
        _check_material(src, mat, raw["material"])
        material = dict(raw["material"])
    elif bench.transport == "simulated":
        raise ConfigError(f"{src}: [material]: missing section: the simulated bench needs a material")
    if "simulator" in raw and not isinstance(raw["simulator"], Mapping):
        raise ConfigError(f"{src}: [simulator]: expected a table")
    cfg = BenchConfig(path, bench, axes, motion, detector, calibration, plan, material, dict(raw))
    _check_cross(cfg)
    return cfg


def _check_material(src: str, mat: Any, raw: Mapping[str, Any]) -> None:
    """What the material's own validation cannot see: a ``tabulated`` lobe's table must be a readable MERL file
    (read now, not when the simulator first needs it), and every lobe must stay finite and within
    :data:`MAX_MATERIAL_BRDF` over the in-plane geometries a capture can measure."""
    import numpy as np

    from reconstruction import merl
    from reconstruction.geometry import inplane_to_dirs

    lobes_raw = raw.get("lobes", [])
    if mat.n_channels > MAX_MATERIAL_CHANNELS:
        raise ConfigError(f"{src}: [material].lobes: spectra of {mat.n_channels} wavelengths; at most "
                          f"{MAX_MATERIAL_CHANNELS} are accepted")
    ti, to = np.meshgrid(np.radians(np.arange(0.0, 90.0, 5.0)), np.radians(np.arange(-85.0, 90.0, 5.0)))
    wi, wo = inplane_to_dirs(ti.ravel(), to.ravel())
    for i, lobe in enumerate(mat.lobes):
        keys = [k for k in lobes_raw[i] if k != "type"] if isinstance(lobes_raw[i], Mapping) else []
        where = f"{src}: [material].lobes[{i}]"
        if getattr(lobe, "type_name", "") == "tabulated":
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                try:
                    lobe.table = merl.read(lobe.path)
                except merl.MerlError as e:
                    raise ConfigError(f"{where}.path: {e}") from None
            for w in caught:
                log.warning("%s.path: %s", where, w.message)
        with np.errstate(all="ignore"):
            f = np.asarray(lobe.eval(wi, wo, mat.n_channels, mat.wavelengths_nm), dtype=float)
        peak = float(np.max(np.abs(f))) if f.size and np.all(np.isfinite(f)) else math.inf
        if not peak <= MAX_MATERIAL_BRDF:
            raise ConfigError(f"{where}.{'/'.join(keys) or 'type'}: the lobe reaches f_r = {peak:.3g} 1/sr, beyond "
                              f"the physical bound {MAX_MATERIAL_BRDF:g} 1/sr that a capture or reconstruction "
                              "accepts; check its parameters")


def _check_cross(cfg: BenchConfig) -> None:
    """Checks that need several sections: the reference geometry must be reachable and measurable."""
    src = str(cfg.path)
    c = cfg.calibration
    if c.mode == "relative":
        ti, to = c.reference_theta_i_deg, c.reference_theta_o_deg
        if not cfg.light.within(ti):
            raise ConfigError(f"{src}: [calibration].reference_theta_i_deg: {ti:g} is outside the light arm "
                              f"soft limits [{cfg.light.min_deg:g}, {cfg.light.max_deg:g}]")
        if not cfg.det_axis.within(to):
            raise ConfigError(f"{src}: [calibration].reference_theta_o_deg: {to:g} is outside the detector arm "
                              f"soft limits [{cfg.det_axis.min_deg:g}, {cfg.det_axis.max_deg:g}]")
        sep = abs(ti + to)
        if sep < max(cfg.bench.min_separation_deg, cfg.bench.blind_spot_half_width_deg):
            raise ConfigError(f"{src}: [calibration].reference_theta_o_deg: the reference geometry ({ti:g}, "
                              f"{to:g}) puts the arms {sep:g} deg apart, inside the collision zone / blind spot")
    park_sep = abs(cfg.light.park_deg + cfg.det_axis.park_deg)
    if park_sep < cfg.bench.min_separation_deg:
        raise ConfigError(f"{src}: [axes.detector].park_deg: parked arms would be {park_sep:g} deg apart, "
                          f"closer than min_separation_deg = {cfg.bench.min_separation_deg:g}")
    if cfg.detector.saturation <= 0:  # pragma: no cover - checked by the field
        raise ConfigError(f"{src}: [detector].saturation: must be > 0")


def _open_text(path: Path, what: str, limit: int = MAX_CONFIG_BYTES) -> str:
    """The UTF-8 text of a config-like file; every failure is a :class:`ConfigError` naming the file."""
    try:
        st = path.stat()
    except FileNotFoundError:
        raise ConfigError(f"{path}: no such file") from None
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror or e})") from None
    if stat.S_ISDIR(st.st_mode):
        raise ConfigError(f"{path}: is a directory, expected {what}")
    if not stat.S_ISREG(st.st_mode):
        raise ConfigError(f"{path}: not a regular file (a device or a pipe), expected {what}")
    if st.st_size > limit:
        raise ConfigError(f"{path}: {st.st_size} bytes; {what} is at most {limit} bytes")
    try:
        with open(path, "rb") as fh:
            data = fh.read(limit + 1)
    except OSError as e:
        raise ConfigError(f"{path}: cannot read ({e.strerror or e})") from None
    try:
        return data.decode("utf-8-sig")  # a byte-order mark (Windows editors write one) is not part of the text
    except UnicodeDecodeError as e:
        line = data.count(b"\n", 0, e.start) + 1
        raise ConfigError(f"{path}:{line}: not a UTF-8 text file ({e.reason} at byte {e.start}); {what} is "
                          "UTF-8 TOML") from None


def load_config(path: str | Path) -> BenchConfig:
    """Read and validate the bench file at ``path`` (raises :class:`ConfigError`)."""
    path = Path(path)
    text = _open_text(path, "a TOML bench file")
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as e:
        raise ConfigError(f"{path}: invalid TOML: {e}") from None
    except RecursionError:
        raise ConfigError(f"{path}: invalid TOML: arrays or tables nested too deeply") from None
    return config_from_dict(raw, path)
