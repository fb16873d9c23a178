"""What a resume must not change: the fingerprint of everything that gives a sample its meaning.

A capture records, in its slice metadata, ``config_fingerprint``: every setting that changes what a sample *is*
(the material, the simulated source and detector, the calibration, the detector and its integration time, the
axes' scale and zero, the arrival tolerance and settling, the plan's points and repeats), and
``config_settings``: the settings that cannot change a sample (timeouts, retries, polling, speeds, ports, the
simulator's seed, time scale and faults). A ``--resume`` compares both with the config it is given: any
difference of the first kind is refused, naming each key with its old and new value; differences of the second
kind are allowed and listed in the log. Both are flat ``{"[section].key": value}`` dicts of JSON values; files a
setting points to (a tabulated lobe's table, a reference spectrum) are fingerprinted by content as well.
"""

from __future__ import annotations

import hashlib
import json
import math
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any

from acquisition.config import BenchConfig

__all__ = ["fingerprint", "settings", "differences", "describe_differences", "NOT_SET"]

NOT_SET = "(not set)"

#: [simulator] keys that change what the detector reads (the others: seed, time scale, stepper speeds, homing,
#: faults, cannot change the meaning of a sample).
SIMULATOR_MEANINGFUL = ("source_power", "detector_solid_angle_sr", "aperture_samples", "dark_offset", "read_noise",
                        "shot_noise", "adc_bits", "gain", "backlash_deg", "settle_time_s", "settle_ringing_deg",
                        "input_noise", "input_offset", "electrons_per_count", "frontend")
SIMULATOR_HARMLESS = ("seed", "time_scale", "stepper_velocity_deg_s", "stepper_acceleration_deg_s2",
                      "homing_required", "grbl_build")
PLAN_MEANINGFUL = ("theta_i_deg", "theta_i_min_deg", "theta_i_max_deg", "theta_i_step_deg", "theta_o_min_deg",
                   "theta_o_max_deg", "theta_o_step_deg", "points", "repeats", "scene", "sample_name")
PLAN_HARMLESS = ("order", "strict", "dark_at_end")


def _norm(v: Any) -> Any:
    """A JSON value that compares equal for equal settings (1 and 1.0 alike; long lists by their hash)."""
    if isinstance(v, bool) or v is None or isinstance(v, str):
        return v
    if isinstance(v, (int, float)):
        return float(v) if math.isfinite(float(v)) else str(v)
    if isinstance(v, Mapping):
        return {str(k): _norm(x) for k, x in sorted(v.items())}
    if isinstance(v, (list, tuple)):
        items = [_norm(x) for x in v]
        if len(items) > 16:
            digest = hashlib.sha256(json.dumps(items, sort_keys=True).encode()).hexdigest()[:12]
            return f"{len(items)} values, sha256 {digest}"
        return items
    return str(v)


def _file_digest(path: str | Path) -> str:
    try:
        h = hashlib.sha256()
        with open(path, "rb") as fh:
            for block in iter(lambda: fh.read(1 << 20), b""):
                h.update(block)
        return f"sha256 {h.hexdigest()[:16]}"
    except OSError as e:
        return f"unreadable ({e.strerror or e})"


def _flatten(prefix: str, v: Any, out: dict[str, Any]) -> None:
    if isinstance(v, Mapping):
        for k in sorted(v):
            _flatten(f"{prefix}.{k}", v[k], out)
    elif isinstance(v, list) and v and all(isinstance(x, Mapping) for x in v):
        for i, x in enumerate(v):
            _flatten(f"{prefix}[{i}]", x, out)
    else:
        out[prefix] = _norm(v)


def _section(name: str, raw: Mapping[str, Any], keys: Iterable[str]) -> dict[str, Any]:
    return {f"[{name}].{k}": _norm(raw[k]) if k in raw else NOT_SET for k in keys}


def _raw(cfg: BenchConfig, *path: str) -> Mapping[str, Any]:
    d: Any = cfg.raw
    for p in path:
        d = d.get(p, {}) if isinstance(d, Mapping) else {}
    return d if isinstance(d, Mapping) else {}


def fingerprint(cfg: BenchConfig, plan_fingerprint: str) -> dict[str, Any]:
    """Every setting of ``cfg`` that changes the meaning of a sample, as ``{"[section].key": value}``;
    ``plan_fingerprint`` (the plan's own hash of its points, repeats and refinement, scene included) is one of
    them."""
    fp: dict[str, Any] = {"[bench].transport": cfg.bench.transport, "[bench].motion": cfg.bench.motion}
    for name, ax in sorted(cfg.axes.items()):
        for k in ("units_per_deg", "zero_offset", "direction"):
            fp[f"[axes.{name}].{k}"] = _norm(getattr(ax, k))
    fp["[motion].tolerance_deg"] = _norm(cfg.motion.tolerance_deg)
    fp["[motion].settle_s"] = _norm(cfg.motion.settle_s)
    d = cfg.detector
    for k in ("type", "integration_time_s", "saturation", "auto_range", "min_integration_time_s"):
        fp[f"[detector].{k}"] = _norm(getattr(d, k))
    for k, default in (("solid_angle_sr", None), ("aperture_half_angle_deg", None), ("responsivity", "silicon"),
                       ("gains", None), ("serial_number", None), ("resource", None), ("wavelength_nm", None),
                       ("correct_dark_counts", True), ("correct_nonlinearity", True)):
        # the optics and the USB detectors' settings: only when given (fingerprints of earlier files stay equal)
        if getattr(d, k) != default:
            fp[f"[detector].{k}"] = _norm(getattr(d, k))
    for k, default in (("source_divergence_deg", 0.0), ("beam_diameter_mm", None), ("sample_diameter_mm", None),
                       ("source_spectrum", "halogen-3000K")):
        if getattr(cfg.bench, k) != default:
            fp[f"[bench].{k}"] = _norm(getattr(cfg.bench, k))
    c = cfg.calibration
    fp["[calibration].mode"] = c.mode
    if c.mode == "relative":
        fp["[calibration].reference_reflectance"] = _norm(c.reference_reflectance)
        fp["[calibration].reference_spectrum"] = _norm(c.reference_spectrum)
        fp["[calibration].reference_theta_i_deg"] = _norm(c.reference_theta_i_deg)
        fp["[calibration].reference_theta_o_deg"] = _norm(c.reference_theta_o_deg)
    else:
        fp["[calibration].source_power"] = _norm(c.source_power)
        fp["[calibration].detector_solid_angle_sr"] = _norm(c.detector_solid_angle_sr)
    plan_raw = {k: v for k, v in _raw(cfg, "plan").items() if k != "adaptive"}
    fp.update(_section("plan", plan_raw, [k for k in PLAN_MEANINGFUL if k != "repeats"]))
    fp["[plan].repeats"] = _norm(cfg.plan.repeats)
    adaptive = _raw(cfg, "plan", "adaptive")
    for k in sorted(adaptive):
        fp[f"[plan.adaptive].{k}"] = _norm(adaptive[k])
    fp["plan points, repeats and refinement (fingerprint)"] = plan_fingerprint
    if cfg.material is not None:
        _flatten("[material]", dict(cfg.material), fp)
        for i, lobe in enumerate(cfg.material.get("lobes", []) or []):
            if isinstance(lobe, Mapping) and lobe.get("type") == "tabulated" and isinstance(lobe.get("path"), str):
                p = Path(lobe["path"])
                fp[f"[material].lobes[{i}].path (content)"] = _file_digest(p if p.is_absolute() else
                                                                         cfg.base_dir / p)
    if cfg.bench.transport == "simulated":
        fp.update(_section("simulator", _raw(cfg, "simulator"), SIMULATOR_MEANINGFUL))
        spec = _raw(cfg, "simulator", "spectrometer")
        fp.update(_section("simulator.spectrometer", spec, ("wl_min_nm", "wl_max_nm", "wl_step_nm")))
    return {k: fp[k] for k in sorted(fp)}


def settings(cfg: BenchConfig) -> dict[str, Any]:
    """The settings of ``cfg`` that cannot change a sample (a resume may change them; the log lists them)."""
    st: dict[str, Any] = {}
    b = cfg.bench
    for k in ("name", "dynamixel_port", "dynamixel_baudrate", "serial_port", "serial_baudrate", "serial_timeout_s",
              "min_separation_deg", "blind_spot_half_width_deg", "simulator_command"):
        st[f"[bench].{k}"] = _norm(getattr(b, k))
    for name, ax in sorted(cfg.axes.items()):
        for k in ("id", "model", "min_deg", "max_deg", "park_deg"):
            st[f"[axes.{name}].{k}"] = _norm(getattr(ax, k))
    m = cfg.motion
    for k in ("profile_velocity", "profile_acceleration", "velocity_deg_s", "acceleration_deg_s2", "timeout_s",
              "retries", "poll_interval_s"):
        st[f"[motion].{k}"] = _norm(getattr(m, k))
    st["[detector].dark_repeats"] = _norm(cfg.detector.dark_repeats)
    if cfg.detector.source_off != "auto":
        st["[detector].source_off"] = _norm(cfg.detector.source_off)
    st["[calibration].reference_repeats"] = _norm(cfg.calibration.reference_repeats)
    st.update(_section("plan", _raw(cfg, "plan"), PLAN_HARMLESS))
    if cfg.bench.transport == "simulated":
        st.update(_section("simulator", _raw(cfg, "simulator"), SIMULATOR_HARMLESS))
        faults = _raw(cfg, "simulator", "faults")
        for k in sorted(faults):
            st[f"[simulator.faults].{k}"] = _norm(faults[k])
    return {k: st[k] for k in sorted(st)}


def differences(old: Mapping[str, Any], new: Mapping[str, Any]) -> list[tuple[str, Any, Any]]:
    """(key, old value, new value) for every key whose value differs (a key missing on one side: NOT_SET)."""
    out = []
    for k in sorted(set(old) | set(new)):
        a, b = old.get(k, NOT_SET), new.get(k, NOT_SET)
        if _norm(a) != _norm(b):
            out.append((k, a, b))
    return out


def _show(v: Any) -> str:
    text = v if v == NOT_SET else json.dumps(v)
    return text if len(text) <= 80 else text[:60] + "..."


def describe_differences(diffs: Iterable[tuple[str, Any, Any]]) -> str:
    """``[plan].theta_o_step_deg: 5.0 -> 2.0; [simulator].gain: 1.0 -> 2.0``."""
    return "; ".join(f"{k}: {_show(a)} -> {_show(b)}" for k, a, b in diffs)
