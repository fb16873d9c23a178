"""Bench configuration: load a TOML bench file and validate every key before anything moves.

A bench file has the sections ``[bench]``, ``[axes.light]``, ``[axes.detector]`` (and optional
``[axes.stage]``), ``[motion]``, ``[detector]``, ``[calibration]`` and ``[plan]`` (see ``configs/*.toml``, whose
comments document each key). ``[material]`` (the simulated sample) is validated with
``reconstruction.core.models.Material.from_dict``; ``[simulator]`` and its sub-tables belong to ``gonio-sim``,
which validates them (``gonio-sim check``, run by ``gonio-capture --check``; ``gonio-sim serve`` refuses a bad
file with exit status 2 when a capture starts it); here they only have to be tables. Any other section or key is
an error.

Every error is a :class:`~acquisition.errors.ConfigError` whose message names the file and the key, e.g.
``configs/x.toml: [axes.light].max_deg: expected a number, got "high"``. Angles in degrees, times in
seconds.
"""

from __future__ import annotations

import difflib
import logging
import math
import sys
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from acquisition.devices import grbl_settings
from acquisition.errors import ConfigError
from acquisition.plans.planconfig import (
    _Table,  # one reader of a table against its schema, errors as ConfigError
    read_plan,
)
from reconstruction.schema import SchemaError, files
from reconstruction.schema import describe as _describe
from reconstruction.schema.bench import (
    DXL_MODELS,
    Axis,
    AxisTable,
    BenchTable,
    CalibrationTable,
    Detector,
    DetectorTable,
    MotionTable,
    PlanTable,
)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - Python 3.10 only
    import tomli as tomllib

__all__ = ["CalibrationConfig", "BenchConfig", "load_config", "config_from_dict"]

TRANSPORTS = ("dynamixel", "serial", "simulated")
DXL_POSITION_RANGE = (0, 4095)  # position mode (operating mode 3), one turn

_TOP_SECTIONS = ("bench", "axes", "motion", "detector", "calibration", "plan", "material", "simulator")

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


class CalibrationConfig:
    """``[calibration]`` as a capture uses it: a thin view of its table (every key read through, e.g. ``mode``,
    ``reference_theta_i_deg``), whose ``reference_spectrum`` is the CSV's data, ``((wavelengths_nm, ...),
    (reflectance, ...))`` or None; the file's own value, the CSV's path, is ``reference_spectrum_path``."""

    __slots__ = ("table", "reference_spectrum")

    def __init__(self, table: CalibrationTable,
                 reference_spectrum: tuple[tuple[float, ...], tuple[float, ...]] | None = None) -> None:
        self.table = table
        self.reference_spectrum = reference_spectrum

    def __getattr__(self, key: str) -> Any:
        if key.startswith("_") or key in self.__slots__:  # not a key of the table (copy, pickle)
            raise AttributeError(key)
        return getattr(self.table, key)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, CalibrationConfig) and (self.table, self.reference_spectrum) == (
            other.table, other.reference_spectrum)

    def __repr__(self) -> str:
        return f"CalibrationConfig({self.table!r})"

    @property
    def reference_spectrum_path(self) -> str | None:
        """``[calibration].reference_spectrum`` as the file gives it (the CSV's path), or None."""
        return self.table.reference_spectrum

    def to_meta(self) -> dict[str, Any]:
        t = self.table
        d: dict[str, Any] = {"mode": t.mode}
        if t.mode == "relative":
            if t.reference_spectrum:
                d["reference_spectrum"] = t.reference_spectrum
            else:
                d["reference_reflectance"] = t.reference_reflectance
            d["reference_theta_i_deg"] = t.reference_theta_i_deg
            d["reference_theta_o_deg"] = t.reference_theta_o_deg
        else:
            d["source_power"] = t.source_power
            d["detector_solid_angle_sr"] = t.detector_solid_angle_sr
        return d


@dataclass
class BenchConfig:
    """A validated bench file: its tables as the schema's structs (:mod:`reconstruction.schema.bench`), the values
    the reader resolves stored in their fields. ``raw`` is the parsed TOML, ``path`` the file, ``base_dir`` its
    directory."""

    path: Path
    bench: BenchTable
    axes: dict[str, Axis]
    motion: MotionTable
    detector: Detector
    calibration: CalibrationConfig
    plan: PlanTable
    material: dict[str, Any] | None
    raw: dict[str, Any] = field(default_factory=dict)

    @property
    def base_dir(self) -> Path:
        return self.path.resolve().parent

    @property
    def light(self) -> Axis:
        return self.axes["light"]

    @property
    def det_axis(self) -> Axis:
        return self.axes["detector"]

    @property
    def sample_name(self) -> str | None:
        if self.plan.sample_name:
            return self.plan.sample_name
        if self.material is not None:
            return str(self.material.get("name", "material"))
        return None


# --- section readers -----------------------------------------------------------------------------------------


def _read_bench(src: str, raw: Any, board_detector: bool = True, motion_type: Any = None) -> BenchTable:
    t = _Table(src, "bench", raw, BenchTable)
    transport = t["transport"]
    motion = grbl_settings.motion_kind(src, t["motion"], motion_type, transport)
    if transport == "simulated":
        if motion is None:
            raise t.error("motion", 'missing key: a simulated bench needs motion = "dynamixel", "serial" or "grbl"')
    elif motion == "grbl":  # GRBL's own port is [motion.grbl].port; serial_port is the detector board's
        if transport != "serial":
            raise t.error("transport", f'is "{transport}", but the arms are on GRBL ([motion].type = "grbl"): use '
                                       'transport = "serial" (the detector board) or "simulated"')
        if not t["serial_port"]:
            raise t.error("serial_port", 'missing: the detector board needs a port, e.g. "/dev/ttyACM1" (GRBL\'s '
                                         "is [motion.grbl].port)")
    else:
        if motion is not None and motion != transport:
            raise t.error("motion", f'is {_describe(motion)} but transport is "{transport}"; leave motion out '
                                    "or make them equal (motion is for simulated benches)")
        motion = transport
        if transport == "dynamixel" and not t["dynamixel_port"]:
            raise t.error("dynamixel_port", "missing: a Dynamixel bench needs the servo bus port, e.g. "
                                            '"/dev/ttyUSB0"')
        if not t["serial_port"] and (board_detector or transport == "serial"):
            raise t.error("serial_port", "missing: the serial controller (detector"
                                         + (" and stepper axes" if transport == "serial" else "")
                                         + ') needs a port, e.g. "/dev/ttyACM0"')
    b, d = t["beam_diameter_mm"], t["sample_diameter_mm"]
    if (b is None) != (d is None):
        given, missing = ("beam_diameter_mm", "sample_diameter_mm") if d is None else ("sample_diameter_mm",
                                                                                         "beam_diameter_mm")
        raise t.error(missing, f"missing: {given} is given; the footprint needs both diameters (mm)")
    return t.build(transport=transport, motion=motion)


def _read_axis(src: str, name: str, raw: Any, motion: str) -> Axis:
    sec = f"axes.{name}"
    t = _Table(src, sec, raw, AxisTable)
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
    ax = Axis(name=name, **t.values)
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


def _read_motion(src: str, raw: Any, motion: str) -> MotionTable:
    t = _Table(src, "motion", raw, MotionTable, skip=("grbl",))  # [motion.grbl]: grbl_settings.read_grbl
    if t.given("grbl") and motion != "grbl":
        raise t.error("grbl", f'is for a GRBL bench ([motion].type = "grbl"); this bench\'s motion is {motion!r}')
    if t["type"] is not None and t["type"] != motion:
        raise t.error("type", f"is {_describe(t['type'])} but [bench] says motion {_describe(motion)}")
    if motion == "dynamixel":
        for k in ("profile_velocity", "profile_acceleration"):
            if t[k] is None:
                raise t.error(k, "missing key: a Dynamixel bench needs the profile (0 = unlimited)")
    if t["tolerance_deg"] > 5:
        raise t.error("tolerance_deg", f"{t['tolerance_deg']:g} deg is not a position tolerance (max 5)")
    return t.build(profile_velocity=t["profile_velocity"] or 0, profile_acceleration=t["profile_acceleration"] or 0)


def _read_detector(src: str, raw: Any, base_dir: Path, source_spectrum: str, sim_raw: Any) -> Detector:
    from reconstruction.schema.optics import band_weights, spectrum_of

    t = _Table(src, "detector", raw, DetectorTable)
    if t["min_integration_time_s"] > t["integration_time_s"]:
        raise t.error("min_integration_time_s", f"{t['min_integration_time_s']:g} s is longer than "
                                                f"integration_time_s = {t['integration_time_s']:g} s")
    if t.given("solid_angle_sr") and t.given("aperture_half_angle_deg"):
        raise t.error("aperture_half_angle_deg", "give either solid_angle_sr or aperture_half_angle_deg, not both")
    values = dict(t.values)
    old = sim_raw.get("detector_solid_angle_sr") if isinstance(sim_raw, Mapping) else None
    if old is not None:
        if t.given("solid_angle_sr") or t.given("aperture_half_angle_deg"):
            raise ConfigError(f"{src}: [simulator].detector_solid_angle_sr: the detector's acceptance is "
                              "[detector].solid_angle_sr now; remove the old key")
        if isinstance(old, (int, float)) and not isinstance(old, bool) and 0 <= old <= 0.5:
            values["solid_angle_sr"] = float(old)  # an older file: the simulator's key keeps working
    if t["saturation"] is None and t["type"] in ("photodiode", "spectrometer"):
        raise t.error("saturation", "missing key: the detector's saturation (raw counts); only the seabreeze and "
                                    "pm100 types read it from the device")
    if t["type"] == "pm100" and t["min_integration_time_s"] != t["integration_time_s"]:
        if t.given("min_integration_time_s"):
            log.info("%s: [detector].min_integration_time_s: a power meter ranges over its power ranges, not "
                     "over averaging; ignored", src)
        values["min_integration_time_s"] = t["integration_time_s"]
    weights = None
    if t["type"] in ("photodiode", "pm100"):
        try:
            weights = band_weights(spectrum_of(t["responsivity"], "responsivity", base_dir,
                                               f"{src}: [detector].responsivity"),
                                   spectrum_of(source_spectrum, "source", base_dir, f"{src}: [bench].source_spectrum"))
        except SchemaError as e:
            raise ConfigError(str(e)) from None
    gains = tuple(sorted(t["gains"])) if t["gains"] is not None else None
    if gains is not None and t["type"] not in ("photodiode", "pm100"):
        log.info("%s: [detector].gains: a spectrometer ranges over integration time only; the gains (a photodiode "
                 "amplifier's) are not used", src)
        gains = None
    return Detector(**{**values, "gains": gains, "band_weights": weights})


def read_spectrum_csv(path: Path, where: str) -> tuple[tuple[float, ...], tuple[float, ...]]:
    """Read a ``wavelength_nm,reflectance`` CSV (:func:`reconstruction.schema.files.read_spectrum_csv`)."""
    try:
        return files.read_spectrum_csv(path, where)
    except SchemaError as e:
        raise ConfigError(str(e)) from None


def _read_calibration(src: str, raw: Any, base_dir: Path) -> CalibrationConfig:
    t = _Table(src, "calibration", raw, CalibrationTable)
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
    return CalibrationConfig(t.build(reference_theta_i_deg=t["reference_theta_i_deg"] if t["reference_theta_i_deg"]
                               is not None else 0.0,
                               reference_theta_o_deg=t["reference_theta_o_deg"] if t["reference_theta_o_deg"]
                               is not None else 10.0), spectrum)


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
    det_raw = raw["detector"]
    board = not (isinstance(det_raw, Mapping) and det_raw.get("type") in ("seabreeze", "pm100"))
    bench = _read_bench(src, raw["bench"], board,
                        raw["motion"].get("type") if isinstance(raw["motion"], Mapping) else None)
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
    if bench.motion == "grbl":
        motion = grbl_settings.read_grbl(src, raw["motion"], motion, axes, bench.transport)
    detector = _read_detector(src, raw["detector"], path.resolve().parent, bench.source_spectrum,
                              raw.get("simulator"))
    calibration = _read_calibration(src, raw["calibration"], path.resolve().parent)
    plan = read_plan(src, raw["plan"], detector, axes)
    material = None
    if "material" in raw:
        from reconstruction.core.models import Material, MaterialError

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

    from reconstruction.core.geometry import inplane_to_dirs
    from reconstruction.core.merltable import MerlError
    from reconstruction.core.models import read_lobe_table

    lobes_raw = raw.get("lobes", [])
    if mat.n_channels > MAX_MATERIAL_CHANNELS:
        raise ConfigError(f"{src}: [material].lobes: spectra of {mat.n_channels} wavelengths; at most "
                          f"{MAX_MATERIAL_CHANNELS} are accepted")
    ti, to = np.meshgrid(np.radians(np.arange(0.0, 90.0, 5.0)), np.radians(np.arange(-85.0, 90.0, 5.0)))
    wi, wo = inplane_to_dirs(ti.ravel(), to.ravel())
    for i, lobe in enumerate(mat.lobes):
        keys = [k for k in lobes_raw[i] if k != "type"] if isinstance(lobes_raw[i], Mapping) else []
        where = f"{src}: [material].lobes[{i}]"
        try:
            for note in read_lobe_table(lobe, where):
                log.warning("%s", note)
        except MerlError as e:
            raise ConfigError(str(e)) from None
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
    if cfg.detector.monitor and (c.mode != "relative" or not cfg.detector.on_board):
        why = "[calibration].mode = \"relative\"" if c.mode != "relative" else \
            "the detector board (type photodiode or spectrometer)"
        raise ConfigError(f"{src}: [detector].monitor: ratio readings need {why}: the monitor's rate is compared "
                          "with the white reference's, which the board reports")
    if cfg.detector.saturation is not None and cfg.detector.saturation <= 0:  # pragma: no cover - the field
        raise ConfigError(f"{src}: [detector].saturation: must be > 0")


def _open_text(path: Path, what: str, limit: int = MAX_CONFIG_BYTES) -> str:
    """The UTF-8 text of a config-like file (:func:`reconstruction.schema.files.open_text`); errors are
    :class:`ConfigError` naming the file."""
    try:
        return files.open_text(path, what, limit)
    except SchemaError as e:
        raise ConfigError(str(e)) from None


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
