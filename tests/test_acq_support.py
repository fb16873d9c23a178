"""Helpers for the acquisition tests (config variants, ground truth, CLI runs); no tests here."""

from __future__ import annotations

import json
import math
import os
import subprocess
import sys
import warnings
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice
from reconstruction.formats.slicefile import read_slice
from tests.helpers import deep_merge

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
SIMULATED = REPO / "configs" / "simulated.toml"

#: Small, fast variant of configs/simulated.toml used by the hardware-in-the-loop tests.
FAST: dict[str, Any] = {
    "bench": {"serial_timeout_s": 0.25},
    "plan": {"theta_i_deg": [30.0], "theta_o_min_deg": -70.0, "theta_o_max_deg": 70.0, "theta_o_step_deg": 5.0,
             "repeats": 4},
    "simulator": {"time_scale": 0.0},
}


def base_raw() -> dict[str, Any]:
    with open(SIMULATED, "rb") as fh:
        return tomllib.load(fh)


def make_raw(*overs: dict[str, Any], fast: bool = True) -> dict[str, Any]:
    raw = base_raw()
    if fast:
        raw = deep_merge(raw, FAST)
    for o in overs:
        raw = deep_merge(raw, o)
    return raw


def write_config(path: Path, raw: dict[str, Any]) -> Path:
    path.write_text(tomli_w.dumps(raw), encoding="utf-8")
    return path


def read(path: Path) -> Slice:
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return read_slice(path)


def keys(s: Slice) -> list[tuple[float, float]]:
    return [(round(float(a), 6), round(float(b), 6)) for a, b in zip(s.theta_i_deg, s.theta_o_deg, strict=True)]


def quantised(raw: dict[str, Any], axis: str, deg: np.ndarray) -> np.ndarray:
    """Angle the simulated arm actually reaches: the goal rounded to whole controller units."""
    a = raw["axes"][axis]
    upd, z, d = a["units_per_deg"], a["zero_offset"], a["direction"]
    return (np.round(z + d * upd * deg) - z) / (d * upd)


def band_vector(n_channels: int, wl: Any = None) -> np.ndarray:
    """(C,) weights of a material's channels in the photodiode's one channel (silicon x halogen-3000K over 380-780
    nm), from colour-science's own Mallett-Yuksel recovery (RGB) or the material's wavelengths (spectral)."""
    grid = np.arange(380.0, 781.0, 5.0)
    resp = np.interp(grid, [350, 400, 450, 500, 550, 600, 650, 700, 750, 800],
                     [0.08, 0.12, 0.20, 0.27, 0.32, 0.37, 0.41, 0.45, 0.49, 0.53])
    planck = grid ** -5.0 / np.expm1(1.4387769e7 / (grid * 3000.0))
    w = resp * planck / np.sum(resp * planck)
    if n_channels == 1:
        return np.ones(1)
    if wl is not None:
        eye = np.eye(n_channels)
        return np.array([w @ np.interp(grid, np.asarray(wl, float), eye[j]) for j in range(n_channels)])
    import colour

    return np.array([w @ np.interp(grid, sd.wavelengths, sd.values) for sd in
                     (colour.recovery.RGB_to_sd_Mallett2019(e) for e in np.eye(3))])


def _instrument(raw: dict[str, Any]) -> Any:
    from reconstruction.instrument.response import Instrument

    det, b, sim = raw["detector"], raw["bench"], raw.get("simulator", {})
    omega = det.get("solid_angle_sr", sim.get("detector_solid_angle_sr", 1e-3))
    return Instrument(float(omega), float(b.get("source_divergence_deg", 0.0)))


def ground_truth(raw: dict[str, Any], s: Slice) -> np.ndarray:
    """f_r on the slice's channels from the config's [material], as the simulator's detector sees it: averaged
    over the detector's cone and the source's divergence (reconstruction.instrument.response, tested on its own
    against a brute-force integral), the photodiode's band, and the footprint (the calibration corrects for it)."""
    from reconstruction.instrument.response import instrument_average

    mat = Material.from_dict(raw["material"])
    ti = quantised(raw, "light", s.theta_i_deg)
    to = quantised(raw, "detector", s.theta_o_deg)
    f = instrument_average(mat, ti, to, _instrument(raw))
    if s.kind == "grey":
        return f @ band_vector(f.shape[-1], mat.wavelengths_nm if f.shape[-1] > 3 else None)[:, None]
    wl = s.wavelengths_nm
    assert wl is not None
    if f.shape[-1] == 3:  # RGB material on a spectrometer: colour-science's Mallett-Yuksel 2019 spectra
        import colour

        sds = [colour.recovery.RGB_to_sd_Mallett2019(row) for row in f]  # independent of the simulator's code
        return np.stack([np.interp(wl, sd.wavelengths, sd.values) for sd in sds])
    return np.broadcast_to(f, (len(s), wl.size)) if f.shape[-1] == 1 else f


def integration_times(out: Path, s: Slice) -> np.ndarray:
    """(N, 2) setting (integration time in s, gain; (N,) times when the gain is not switched) each sample of
    ``out``/slice.csv was read at: the reference
    setting (the configured time; the highest gain, or 0 = no gains), or the auto-ranged one recorded in
    ``out``/capture.json."""
    sidecar = json.loads((out / "capture.json").read_text(encoding="utf-8"))
    ar = sidecar.get("auto_range", {})
    points, gains = ar.get("points", {}), ar.get("point_gains", {})
    g_ref = max(ar["ladder_gains"]) if ar.get("ladder_gains") else 0.0

    def key(k: str) -> tuple[float, float]:
        return (round(float(k.split(",")[0]), 6), round(float(k.split(",")[1]), 6))

    ranged = {key(k): (float(t), float(gains.get(k, g_ref))) for k, t in points.items()}
    t_ref = float(s.meta["detector"]["integration_time_s"])
    out_ = np.array([ranged.get(k, (t_ref, g_ref)) for k in keys(s)]).reshape(len(s), 2)
    return out_ if g_ref else out_[:, 0]  # without gains: (N,) times


def zscores(raw: dict[str, Any], s: Slice, t_int: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(z, relative error) of every value against the ground truth, with the noise the simulator's model
    predicts (shot, amplifier and ADC noise of the repeats, the dark at the sample's setting, plus the
    reference/dark uncertainty common to the slice).

    ``t_int``: (N, 2) setting (integration time s, gain; 0 = no gains) of each sample (see
    :func:`integration_times`; default: read from the capture.json beside the slice). A sample read at time t and
    gain g is converted to the reference setting (t_ref, g_ref) by ``r = g_ref t_ref / (g t)``."""
    truth = ground_truth(raw, s)
    # the calibration's cosine correction uses the commanded theta_o (and reference angle), the arm reaches the
    # nearest controller unit: what a sample is expected to read differs from f there by cos(reached) / cos(asked)
    cal = s.meta["calibration"]
    to_q = quantised(raw, "detector", s.theta_o_deg)[:, None]
    truth = truth * np.cos(np.radians(to_q)) / np.cos(np.radians(s.theta_o_deg))[:, None]
    if cal["mode"] == "relative":
        ref_o = float(cal["reference_theta_o_deg"])
        truth = truth * math.cos(math.radians(ref_o)) / math.cos(math.radians(
            float(quantised(raw, "detector", np.array([ref_o]))[0])))
    sim = raw["simulator"]
    if t_int is None:
        t_int = integration_times(Path(s.source).parent, s)
    t_int = np.asarray(t_int, dtype=float).reshape(len(s), -1)
    to = quantised(raw, "detector", s.theta_o_deg)[:, None]
    cos_o = np.cos(np.radians(to))
    omega = _instrument(raw).detector_solid_angle_sr
    counts = sim["source_power"] * truth * cos_o * omega  # gain 1, t_ref (the footprint is corrected: left out)
    counts = np.where(np.abs(quantised(raw, "light", s.theta_i_deg)[:, None] + to)
                      < raw["bench"]["blind_spot_half_width_deg"], 0.0, counts)
    t_ref = float(raw["detector"]["integration_time_s"])
    t = t_int[:, :1]
    g = t_int[:, 1:2] if t_int.shape[1] > 1 else np.zeros_like(t)
    det = raw["detector"]
    ranging_gain = det.get("gains") and det.get("type") == "photodiode" and det.get("auto_range", True)
    g_ref = float(np.max(det["gains"])) if ranging_gain else float(np.min(det["gains"])) if det.get("gains") and \
        det.get("type") == "photodiode" else 0.0
    g = np.where(g > 0, g, float(sim.get("gain", 1.0)))
    g_ref = g_ref or float(sim.get("gain", 1.0))
    sens = g * t / t_ref                     # output counts per gain-1 t_ref count
    epc = float(sim.get("electrons_per_count", 1.0))
    noise_var = sim["read_noise"] ** 2 + (g * sim.get("input_noise", 0.0)) ** 2 + 1.0 / 12.0  # output counts
    shot = counts * (t_ref / t) / epc if sim.get("shot_noise", True) else 0.0  # gain-1 t_ref counts
    var = shot + noise_var / sens ** 2
    ref = (np.abs(t - t_ref) < 1e-12 * t_ref) & (np.abs(g - g_ref) < 1e-9 * g_ref)
    dark_var = np.where(ref, 0.0, noise_var / sens ** 2 / raw["detector"].get("dark_repeats", 32))
    if cal["mode"] == "relative":
        net = np.asarray(cal["reference_reading"]["mean"]) - np.asarray(cal["dark"]["mean"])
        k = np.asarray(cal["rho_ref"]) / math.pi * math.cos(math.radians(cal["reference_theta_o_deg"])) / (
            net * cos_o)
    else:
        k = 1.0 / (cal["k_counts"] * cos_o)
    k = k * g_ref  # reference counts are g_ref x gain-1 t_ref counts
    fp = 1.0
    b = raw["bench"]
    if b.get("beam_diameter_mm") and b.get("sample_diameter_mm"):
        from reconstruction.schema.optics import footprint_fraction

        frac = footprint_fraction(quantised(raw, "light", s.theta_i_deg), b["beam_diameter_mm"],
                                  b["sample_diameter_mm"])[:, None]
        fp = np.where(frac >= 0.25, 1.0 / frac, 1.0)  # the calibration's correction scales the noise too
    sigma_stat = np.sqrt(var / s.repeats[:, None] + dark_var) * k * fp
    common = np.asarray(cal["common_relative_uncertainty"])
    sigma = np.sqrt(sigma_stat ** 2 + (truth * common) ** 2)
    return (s.values - truth) / sigma, (s.values - truth) / np.maximum(np.abs(truth), 1e-12)


def run_capture(*args: str, timeout: float = 120.0, env: dict[str, str] | None = None
                ) -> subprocess.CompletedProcess[str]:
    """``gonio-capture ARGS`` in a child process (for signal tests and exit codes)."""
    e = dict(os.environ)
    e.update(env or {})
    return subprocess.run([sys.executable, "-m", "acquisition.cli", *args], cwd=REPO, capture_output=True,
                          text=True, timeout=timeout, env=e)


def popen_capture(*args: str) -> subprocess.Popen[str]:
    return subprocess.Popen([sys.executable, "-m", "acquisition.cli", *args], cwd=REPO, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)
