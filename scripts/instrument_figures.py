"""The figures of docs/instrument.md, one per effect of the instrument model, from the shipped simulated bench
(configs/simulated.toml) and the simulator's own physics:

- ``instrument-aperture.png``: a sharp ggx lobe read through the detector's cone (the reading the simulator
  gives, :func:`reconstruction.instrument.response.instrument_average`) against f at the cone's centre;
- ``instrument-footprint.png``: the fraction of the beam that falls on the sample against theta_i (the light a
  real bench loses at grazing incidence, and what the calibration corrects);
- ``instrument-gains.png``: the gain ranging ladder: the signal range each setting (gain, integration time)
  measures, from its noise floor to its saturation, and where a black felt and a mirror fall.

Run: ``.venv/bin/python scripts/instrument_figures.py --out docs`` (a few seconds); it prints the figures it
quotes (the dynamic range of the config).
"""

from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from reconstruction.core.geometry import inplane_to_dirs  # noqa: E402
from reconstruction.core.models import Material  # noqa: E402
from reconstruction.instrument.response import Instrument, instrument_average  # noqa: E402
from reconstruction.schema.optics import footprint_fraction, footprint_limit_deg  # noqa: E402


def aperture_figure(out: Path) -> dict[str, float]:
    """Readings of ggx lobes (alpha 1e-3, 5e-3, 0.02) around the mirror direction at theta_i = 30 deg through the
    1e-3 sr cone (half angle 1.03 deg), against f at the centre."""
    import matplotlib.pyplot as plt

    inst = Instrument(1e-3, 0.25)
    to = np.linspace(26.0, 34.0, 321)
    fig, ax = plt.subplots(figsize=(7.0, 4.2))
    figures = {}
    for alpha, colour in ((1e-3, "tab:red"), (5e-3, "tab:orange"), (0.02, "tab:blue")):
        mat = Material.from_dict({"name": "m", "lobes": [{"type": "ggx", "alpha": alpha, "specular": 0.95}]})
        wi, wo = inplane_to_dirs(np.radians(np.full_like(to, 30.0)), np.radians(to))
        point = mat.eval(wi, wo)[:, 0]
        reading = instrument_average(mat, np.full_like(to, 30.0), to, inst)[:, 0]
        ax.semilogy(to, np.maximum(point, 1e-3), "--", color=colour, lw=1.0,
                    label=f"f at the centre, alpha {alpha:g}")
        ax.semilogy(to, np.maximum(reading, 1e-3), "-", color=colour, lw=2.0, label=f"reading, alpha {alpha:g}")
        figures[f"peak_over_reading_alpha_{alpha:g}"] = float(point.max() / reading.max())
        figures[f"energy_in_the_cone_alpha_{alpha:g}"] = float(reading.max() * math.cos(math.radians(30.0)) * 1e-3)
    half = inst.aperture_half_angle_deg
    ax.axvspan(30.0 - half, 30.0 + half, color="0.9", zorder=0,
               label=f"cone at the mirror direction (+-{half:.2f} deg)")
    ax.set_xlabel("theta_o (deg), theta_i = 30 deg")
    ax.set_ylabel("f_r (1/sr)")
    ax.set_ylim(1e-2, 1e6)
    ax.set_title("Aperture blur: a sharp lobe read through a 1e-3 sr detector cone")
    ax.legend(fontsize=7, loc="upper right")
    fig.tight_layout()
    fig.savefig(out / "instrument-aperture.png", dpi=120)
    plt.close(fig)
    return figures


def footprint_figure(out: Path) -> dict[str, float]:
    """Fraction of the beam on the sample against theta_i for the shipped benches' beam and sample diameters."""
    import matplotlib.pyplot as plt

    ti = np.linspace(0.0, 89.0, 891)
    fig, ax = plt.subplots(figsize=(7.0, 4.0))
    figures = {}
    for beam, sample, label in ((10.0, 40.0, "simulated.toml: 10 mm beam, 40 mm sample"),
                                (8.0, 25.0, "dynamixel-bench.toml: 8 mm beam, 25 mm sample"),
                                (10.0, 20.0, "10 mm beam, 20 mm sample")):
        frac = footprint_fraction(ti, beam, sample)
        line, = ax.plot(ti, frac, lw=2.0, label=label)
        lim = footprint_limit_deg(beam, sample)
        ax.axvline(lim, color=line.get_color(), ls=":", lw=1.0)
        figures[f"fraction_at_80_{beam:g}_{sample:g}"] = float(footprint_fraction(80.0, beam, sample))
    ax.axhline(0.25, color="0.5", ls="--", lw=1.0, label="below this the calibration does not correct")
    ax.set_xlabel("theta_i (deg)")
    ax.set_ylabel("fraction of the beam on the sample")
    ax.set_ylim(0.0, 1.05)
    ax.set_title("Footprint: the spot (beam / cos theta_i) overfills the sample")
    ax.legend(fontsize=7, loc="lower left")
    fig.tight_layout()
    fig.savefig(out / "instrument-footprint.png", dpi=120)
    plt.close(fig)
    return figures


def gains_figure(out: Path) -> dict[str, float]:
    """Each setting's measurable range of signal (gain-1 counts at the configured integration time, per point of
    4 repeats): from its noise floor (the dark's std of the mean) to its saturation (80 % headroom)."""
    import matplotlib.pyplot as plt

    from acquisition.config import load_config
    from acquisition.devices.autorange import HEADROOM, settings_ladder
    from simulator.config import load_config as sim_config

    cfg = load_config(ROOT / "configs" / "simulated.toml")
    sim = sim_config(ROOT / "configs" / "simulated.toml").sim
    d = cfg.detector
    repeats = cfg.plan.repeats
    ladder = settings_ladder(d.integration_time_s, d.min_integration_time_s, d.gains)
    fig, ax = plt.subplots(figsize=(7.5, 4.6))
    lows, highs = [], []
    for k, (g, t) in enumerate(ladder):
        g = 1.0 if g is None else g
        sens = g * t / d.integration_time_s
        noise = math.hypot(sim.read_noise, g * sim.input_noise) / math.sqrt(repeats)
        low = noise / sens
        high = (HEADROOM * d.saturation - sim.dark_offset - g * sim.input_offset) / sens
        lows.append(low)
        highs.append(high)
        ax.plot([low, high], [k, k], lw=6, solid_capstyle="butt", color="tab:blue")
        ax.text(high * 1.5, k, f"gain {g:g}, {t:g} s", va="center", fontsize=7)
    p = sim.source_power * cfg.detector.acceptance_sr
    felt = p * 0.01 / math.pi * math.cos(math.radians(70.0))
    mirror = sim.source_power * 0.95
    white = p * 0.99 / math.pi * math.cos(math.radians(10.0))
    for x, name, c in ((felt, "black felt at 70 deg", "k"), (white, "white reference", "tab:green"),
                       (mirror, "mirror's peak", "tab:red")):
        ax.axvline(x, color=c, ls="--", lw=1.0, label=f"{name}: {x:.3g}")
    ax.set_xscale("log")
    ax.set_yticks([])
    ax.set_ylim(-0.8, len(ladder) + 0.3)
    ax.set_xlim(min(lows) / 5, max(highs) * 200)
    ax.invert_yaxis()
    ax.set_xlabel("signal (counts at gain 1 and the configured integration time; noise floor of 4 repeats)")
    ax.legend(fontsize=7, loc="lower left")
    dr = max(highs) / min(lows)
    ax.set_title(f"Gain ranging ladder of configs/simulated.toml: dynamic range {dr:.1e}")
    fig.tight_layout()
    fig.savefig(out / "instrument-gains.png", dpi=120)
    plt.close(fig)
    return {"dynamic_range": dr, "noise_floor_counts": min(lows), "brightest_counts": max(highs),
            "mirror_over_floor": mirror / min(lows), "felt_counts": felt}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--out", default="out/figures",
                    help="folder for the PNG files (default: out/figures; --out docs updates the docs' figures)")
    args = ap.parse_args(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    for name, fn in (("aperture", aperture_figure), ("footprint", footprint_figure), ("gains", gains_figure)):
        for k, v in fn(out).items():
            print(f"{name}: {k} = {v:.4g}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
