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

from reconstruction.geometry import inplane_to_dirs
from reconstruction.models import Material
from reconstruction.slicefile import Slice, read_slice
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


def ground_truth(raw: dict[str, Any], s: Slice) -> np.ndarray:
    """f_r on the slice's channels from the config's [material], as the simulator's detector sees it."""
    mat = Material.from_dict(raw["material"])
    ti = quantised(raw, "light", s.theta_i_deg)
    to = quantised(raw, "detector", s.theta_o_deg)
    wi, wo = inplane_to_dirs(np.radians(ti), np.radians(to))
    f = mat.eval(wi, wo)
    if s.kind == "grey":
        return f.mean(axis=-1, keepdims=True)  # the photodiode reports the mean over the material's channels
    wl = s.wavelengths_nm
    assert wl is not None
    if f.shape[-1] == 3:  # RGB material on a spectrometer: colour-science's Mallett-Yuksel 2019 spectra
        import colour

        sds = [colour.recovery.RGB_to_sd_Mallett2019(row) for row in f]  # independent of the simulator's code
        return np.stack([np.interp(wl, sd.wavelengths, sd.values) for sd in sds])
    return np.broadcast_to(f, (len(s), wl.size)) if f.shape[-1] == 1 else f


def integration_times(out: Path, s: Slice) -> np.ndarray:
    """(N,) integration time (s) each sample of ``out``/slice.csv was read at: the configured one, or the
    auto-ranged setting recorded in ``out``/capture.json."""
    sidecar = json.loads((out / "capture.json").read_text(encoding="utf-8"))
    points = sidecar.get("auto_range", {}).get("points", {})
    ranged = {(round(float(k.split(",")[0]), 6), round(float(k.split(",")[1]), 6)): float(t)
              for k, t in points.items()}
    t_ref = float(s.meta["detector"]["integration_time_s"])
    return np.array([ranged.get(k, t_ref) for k in keys(s)])


def zscores(raw: dict[str, Any], s: Slice, t_int: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(z, relative error) of every value against the ground truth, with the noise the simulator's model
    predicts (shot + read noise of the repeats, plus the reference/dark uncertainty common to the slice).

    ``t_int``: (N,) integration time (s) of each sample (see :func:`integration_times`; default: all at
    ``[detector].integration_time_s``). A sample read at ``t`` was scaled by ``r = t_ref / t``: its shot variance
    by ``r`` (in reference counts), its read noise and the noise of the dark measured at ``t`` by ``r**2``."""
    truth = ground_truth(raw, s)
    sim = raw["simulator"]
    cal = s.meta["calibration"]
    to = quantised(raw, "detector", s.theta_o_deg)[:, None]
    cos_o = np.cos(np.radians(to))
    counts = sim["source_power"] * truth * cos_o * sim["detector_solid_angle_sr"]
    counts = np.where(np.abs(quantised(raw, "light", s.theta_i_deg)[:, None] + to)
                      < raw["bench"]["blind_spot_half_width_deg"], 0.0, counts)
    t_ref = float(raw["detector"]["integration_time_s"])
    r = np.ones((len(s), 1)) if t_int is None else (t_ref / np.asarray(t_int, dtype=float))[:, None]
    read_var = sim["read_noise"] ** 2 + 1.0 / 12.0
    var = (counts * r if sim.get("shot_noise", True) else 0.0) + read_var * r ** 2
    dark_var = np.where(r > 1.0, read_var * r ** 2 / raw["detector"].get("dark_repeats", 32), 0.0)
    if cal["mode"] == "relative":
        net = np.asarray(cal["reference_reading"]["mean"]) - np.asarray(cal["dark"]["mean"])
        k = np.asarray(cal["rho_ref"]) / math.pi * math.cos(math.radians(cal["reference_theta_o_deg"])) / (
            net * cos_o)
    else:
        k = 1.0 / (cal["k_counts"] * cos_o)
    sigma_stat = np.sqrt(var / s.repeats[:, None] + dark_var) * k
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
