"""Configuration of the virtual bench, read from the shared TOML file (``configs/simulated.toml``).

Only the sections the simulator needs are interpreted, and in those only the keys it reads, through the same
schema as ``gonio-capture`` (:mod:`reconstruction.schema.bench`; the other keys are ``gonio-capture``'s to
check). Angles in degrees, times in seconds. The simulator-only keys live in
``[simulator]``, ``[simulator.faults]``, ``[simulator.spectrometer]`` and ``[simulator.misalignment]`` (all
optional, defaults below), which are
validated strictly: unknown keys, wrong types and impossible values are errors (:class:`ConfigError`, whose message
names the file, the table and the key).
"""

from __future__ import annotations

import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import msgspec

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover - exercised on 3.10 only
    import tomli as tomllib

from reconstruction.schema import SchemaError, Table
from reconstruction.schema import describe as _describe
from reconstruction.schema.bench import AXIS_LETTERS, Axis, AxisTable, BenchTable, Detector, DetectorTable, GrblTable
from reconstruction.schema.files import UserFileError, read_user_text
from reconstruction.schema.simulator import FaultsSection, MisalignmentSection, SimulatorSection, SpectrometerSection

#: Largest bench file read (bytes), as gonio-capture's limit.
MAX_CONFIG_BYTES = 512 * 1024


@dataclass
class BenchConfig:
    """Everything the virtual bench needs, as the schema's structs (:mod:`reconstruction.schema.bench`): ``bench``
    (``[bench]``, its ``motion`` resolved with ``[motion].type``), ``axes`` (:class:`~reconstruction.schema.bench.Axis`
    by name), ``detector`` (:class:`~reconstruction.schema.bench.Detector`: ``saturation``, ``solid_angle_sr`` and
    ``gains`` resolved as the simulator reads them; ``kind`` is what it measures), ``sim`` (``[simulator]``),
    ``grbl`` (``[motion.grbl]``), the ``[material]`` table, the raw TOML dict (``raw``) and its directory
    (``base_dir``)."""

    bench: BenchTable
    axes: dict[str, Axis]
    detector: Detector
    sim: SimulatorSection = field(default_factory=SimulatorSection)
    #: ``[motion.grbl]`` (a GRBL bench's controller; ``homing`` defaults to ``[simulator].homing_required``)
    grbl: GrblTable = field(default_factory=GrblTable)
    material: dict[str, Any] = field(default_factory=dict)
    raw: dict[str, Any] = field(default_factory=dict)
    base_dir: Path = field(default_factory=Path.cwd)

    @property
    def motion(self) -> str:
        """The motion hardware: ``"dynamixel"``, ``"serial"`` or ``"grbl"`` (``[bench].motion`` resolved)."""
        return str(self.bench.motion)

    @motion.setter
    def motion(self, value: str) -> None:
        self.bench = msgspec.structs.replace(self.bench, motion=value)

    @property
    def reference_reflectance(self) -> float:
        """The white reference's ``[calibration].reference_reflectance`` (0.99 when not a number)."""
        ref = _table("", "calibration", self.raw.get("calibration")).get("reference_reflectance", 0.99)
        return float(ref) if isinstance(ref, (int, float)) else 0.99

    @property
    def reference_spectrum(self) -> str | None:
        """The white reference's ``[calibration].reference_spectrum`` (a CSV path), or None."""
        return _table("", "calibration", self.raw.get("calibration")).get("reference_spectrum")


class ConfigError(ValueError):
    """An invalid simulator config; the message names the file, the table and the key."""


def _table(src: str, section: str, d: Any) -> dict[str, Any]:
    if d is None:
        return {}
    if not isinstance(d, dict):
        raise ConfigError(f"{src}: [{section}]: expected a table, got {_describe(d)}")
    return d


def _read(src: str, section: str, d: Any, cls: type, strict: bool = False, **kw: Any) -> Table:
    """A table of the bench file read against its schema (reconstruction.schema): the simulator's own tables
    strictly (``strict``), the others' keys it reads type-checked, their other keys left to gonio-capture."""
    try:
        return Table(src, section, d, cls, strict=strict, **kw)
    except SchemaError as e:
        raise ConfigError(str(e)) from None


#: The simulator's defaults of the shared keys it reads when a table leaves them out.
_AXIS_DEFAULTS = {"model": "XM430-W350", "units_per_deg": 4096 / 360, "zero_offset": 2048, "direction": 1,
                  "min_deg": -180.0, "max_deg": 180.0, "park_deg": 0.0}
_DETECTOR_DEFAULTS = {"type": "photodiode", "integration_time_s": 0.01, "repeats": 4, "saturation": 65535}


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
    bench = _read(src, "bench", _table(src, "bench", raw.get("bench")), BenchTable,
                  defaults={"name": "simulated bench", "motion": "dynamixel", "min_separation_deg": 6.0,
                            "blind_spot_half_width_deg": 4.0, "transport": "simulated"})
    axes = {}
    for name, a in _table(src, "axes", raw.get("axes")).items():
        if not isinstance(a, dict):
            continue
        t = _read(src, f"axes.{name}", a, AxisTable, defaults={"id": AXIS_LETTERS.get(name, name), **_AXIS_DEFAULTS})
        axes[name] = Axis(name=name, **t.values)
    for req in ("light", "detector"):
        if req not in axes:
            raise ConfigError(f"{src}: [axes.{req}]: missing table (required)")
    s = _table(src, "simulator", raw.get("simulator"))
    if "aperture_samples" in s:
        raise ConfigError(f"{src}: [simulator].aperture_samples: no longer read: the simulator integrates f cos "
                          "theta_o over the detector's cone exactly; remove the key and give the cone as "
                          "[detector].solid_angle_sr (or aperture_half_angle_deg)")
    faults = _read(src, "simulator.faults", _table(src, "simulator.faults", s.get("faults")), FaultsSection,
                   strict=True)
    spectrometer = _read(src, "simulator.spectrometer", _table(src, "simulator.spectrometer", s.get("spectrometer")),
                         SpectrometerSection, strict=True)
    misalignment = _read(src, "simulator.misalignment", _table(src, "simulator.misalignment", s.get("misalignment")),
                         MisalignmentSection, strict=True)
    sim = _read(src, "simulator", s, SimulatorSection, strict=True,
                skip=("faults", "spectrometer", "misalignment")).build(
        faults=faults.build(), spectrometer=spectrometer.build(), misalignment=misalignment.build())
    if sim.spectrometer.wl_max_nm < sim.spectrometer.wl_min_nm:
        raise ConfigError(f"{src}: [simulator.spectrometer].wl_max_nm: {sim.spectrometer.wl_max_nm:g} is less than "
                          f"wl_min_nm {sim.spectrometer.wl_min_nm:g}")
    n_wl = (sim.spectrometer.wl_max_nm - sim.spectrometer.wl_min_nm) / sim.spectrometer.wl_step_nm + 1
    if n_wl > 4096:
        raise ConfigError(f"{src}: [simulator.spectrometer].wl_step_nm: {n_wl:.0f} wavelengths from "
                          f"{sim.spectrometer.wl_min_nm:g} to {sim.spectrometer.wl_max_nm:g} nm, more than a "
                          "spectrometer has (4096); use a coarser step")
    det = _read(src, "detector", _table(src, "detector", raw.get("detector")), DetectorTable,
                defaults=_DETECTOR_DEFAULTS)
    base = Path(base_dir) if base_dir is not None else Path.cwd()
    solid = _solid_angle(src, det, sim.detector_solid_angle_sr)
    weights = None
    device = det["type"]
    kind = {"seabreeze": "spectrometer", "pm100": "photodiode"}.get(device, device)
    saturation = det["saturation"] if det["saturation"] is not None else float(2 ** int(sim.adc_bits) - 1)
    if kind == "photodiode":
        from reconstruction.schema.optics import band_weights, spectrum_of

        try:
            weights = band_weights(spectrum_of(det["responsivity"], "responsivity", base,
                                               f"{src}: [detector].responsivity"),
                                   spectrum_of(bench["source_spectrum"], "source", base,
                                               f"{src}: [bench].source_spectrum"))
        except SchemaError as e:
            raise ConfigError(str(e)) from None
    _table(src, "calibration", raw.get("calibration"))
    motion_raw = raw.get("motion")
    motion_type = motion_raw.get("type") if isinstance(motion_raw, dict) else None
    grbl_raw = motion_raw.get("grbl") if isinstance(motion_raw, dict) else None
    grbl = _read(src, "motion.grbl", grbl_raw if isinstance(grbl_raw, dict) else {}, GrblTable)
    cfg = BenchConfig(
        bench=bench.build(motion=motion_type if motion_type in ("dynamixel", "serial", "grbl") else bench["motion"]),
        axes=axes,
        detector=Detector(**{**det.values, "saturation": saturation, "solid_angle_sr": solid,
                             "gains": tuple(sorted(det["gains"])) if det["gains"] and device == "photodiode" else None,
                             "band_weights": weights}),
        sim=sim,
        grbl=grbl.build(homing=grbl["homing"] if grbl.given("homing") else sim.homing_required),
        material=dict(_table(src, "material", raw.get("material"))),
        raw=raw,
        base_dir=base,
    )
    if cfg.motion not in ("dynamixel", "serial", "grbl"):
        raise ConfigError(f"{src}: [bench].motion: must be \"dynamixel\", \"serial\" or \"grbl\", got "
                          f"{_describe(cfg.motion)}")
    if cfg.detector.kind not in ("photodiode", "spectrometer"):  # pragma: no cover - the schema's choices
        raise ConfigError(f"{src}: [detector].type: must be \"photodiode\" or \"spectrometer\", got "
                          f"{_describe(cfg.detector.kind)}")
    return cfg


def _solid_angle(src: str, det: Table, old: float | None) -> float:
    """The detector cone (sr): ``[detector].solid_angle_sr`` or ``aperture_half_angle_deg``, else the older
    ``[simulator].detector_solid_angle_sr``, else 1e-3."""
    import math

    new = det.given("solid_angle_sr") or det.given("aperture_half_angle_deg")
    if det.given("solid_angle_sr") and det.given("aperture_half_angle_deg"):
        raise ConfigError(f"{src}: [detector].aperture_half_angle_deg: give either solid_angle_sr or "
                          "aperture_half_angle_deg, not both")
    if old is not None and new:
        raise ConfigError(f"{src}: [simulator].detector_solid_angle_sr: the detector's acceptance is "
                          "[detector].solid_angle_sr now; remove the old key")
    if det.given("solid_angle_sr"):
        return float(det["solid_angle_sr"])
    if det.given("aperture_half_angle_deg"):
        return 2 * math.pi * (1 - math.cos(math.radians(det["aperture_half_angle_deg"])))
    return 1.0e-3 if old is None else float(old)


def load_config(path: str | Path, **overrides: Any) -> BenchConfig:
    """Load the TOML file at ``path``. ``overrides`` set ``[simulator]`` keys (e.g. ``seed=3, time_scale=0``).

    Raises :class:`ConfigError` (a ValueError) naming the file for a missing, unreadable or malformed file."""
    path = Path(path)
    try:
        raw = tomllib.loads(read_user_text(path, "a TOML bench file", MAX_CONFIG_BYTES))
    except UserFileError as e:
        raise ConfigError({"too_big": f"{path}: larger than {MAX_CONFIG_BYTES} bytes; not a bench file",
                           "grew": f"{path}: larger than {MAX_CONFIG_BYTES} bytes; not a bench file",
                           "unreadable": f"{path}: cannot read: {e.why}",
                           "not_utf8": f"{path}: not a UTF-8 text file ({e.why} at byte {e.byte})"}.get(e.kind, str(e))
                          ) from None
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
