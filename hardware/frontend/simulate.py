"""Run the detector's front-end (hardware/frontend/frontend.cir) in ngspice: its DC transfer per range, loop phase
margin, settling after a gain or source switch, and noise at the ADC.

    python hardware/frontend/simulate.py --table [--out hardware/frontend/transfer.json]
    python hardware/frontend/simulate.py --figures

``--table`` writes the per-range transfer table the simulator reads (simulator/world/frontend.py): the DC curve
(photocurrent in A -> ADC input in V, clipping included), offset, slope, swing and settling. ``--figures`` prints
the figures of docs/build-a-bench.md ("The amplifier, simulated"): phase margin, settling, noise per range and the
dynamic range with the ATmega's 10-bit ADC and with an ADS1115. ``--netlist`` and ``--photodiode`` simulate another
netlist or photodiode model in place of the project's (tests/test_frontend_spice.py swaps in a reference model
and the guide's old wiring). Needs ngspice (Debian package ``ngspice``); exits 2 with one line if it is missing.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import math
import re
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
if str(HERE.parents[1]) not in sys.path:  # run as a script from anywhere
    sys.path.insert(0, str(HERE.parents[1]))

from hardware.frontend.netlist import NETLIST, feedback  # noqa: E402

REPO = HERE.parents[1]
TABLE = HERE / "transfer.json"
CONFIG_H = REPO / "firmware" / "detector" / "src" / "config.h"
LIBS = ("photodiode.lib", "mcp6001.lib", "hc4051.lib")
N_RANGES = 5
#: the ADC's reference (the Arduino's 5 V, AVcc) and the op-amp's top of swing the ranges' full scale is taken to
V_ADC = 5.0
#: fractions of a range's full scale (out from Vref to 5 V) at which the DC curve is sampled (beyond 1: clipping)
CURVE = (0.0, 0.005, 0.01, 0.02, 0.05, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7, 0.8, 0.9, 0.95, 1.0, 1.05, 1.2, 2.0, 10.0)
#: the monitor photodiode's fixed feedback resistor (R8 of the netlist, node monitor)
MONITOR_RF = 1e6
#: the ATmega328P's reading: 80 conversions every 125 us (firmware/detector/src/config.h)
SAMPLE_PERIOD_S = 125e-6
NCONV = 80
#: ADCs for the dynamic range. ATmega328P: 10 bits on AVcc = 5 V, LSB 4.89 mV; its datasheet gives no rms noise
#: (absolute accuracy +-2 LSB), so its floor is the quantisation, LSB / sqrt(12). ADS1115 (TI SBAS444) as the
#: firmware sets it (firmware/detector/src/ads1115.h: PGA +-4.096 V, 860 samples/s, differential AIN0 = out -
#: AIN1 = the amplifier's reference): 16 bits, LSB 125 uV; its noise table gives one LSB (125 uV rms) at +-4.096 V
#: at every data rate, 860 SPS included; one conversion passes about DR / 2 = 430 Hz of the amplifier's noise (its
#: sinc filter). Its top is the reference plus 4.096 V (``differential``), below the op-amp's swing or at it.
ADCS = {
    "ATmega328P 10-bit": {"lsb_v": 5.0 / 1024, "noise_v": 5.0 / 1024 / math.sqrt(12), "top_v": 5.0 * 1023 / 1024},
    "ADS1115 16-bit": {"lsb_v": 125e-6, "noise_v": 125e-6, "top_v": 4.096, "band_hz": 430.0, "differential": True},
}


class SpiceError(RuntimeError):
    """ngspice is missing or failed; the message says why in one line."""


def ngspice_problem() -> str | None:
    """None when ngspice runs here, else a one-line reason."""
    if shutil.which("ngspice") is None:
        return "ngspice is not installed (Debian package ngspice; scripts/system-packages.sh installs it)"
    return None


def gain_settle_s(config_h: Path = CONFIG_H) -> float:
    """The firmware's wait after a gain switch (``GAIN_SETTLE_US`` of config.h), in s."""
    m = re.search(r"#define\s+GAIN_SETTLE_US\s+(\d+)", config_h.read_text(encoding="utf-8"))
    if not m:
        raise SpiceError(f"{config_h}: no GAIN_SETTLE_US")
    return int(m.group(1)) * 1e-6


class Circuit:
    """The netlist ``netlist`` (with its libraries from the same folder) and photodiode model ``photodiode``
    (default: the netlist's own photodiode.lib), run by ngspice in a scratch folder."""

    def __init__(self, netlist: Path = NETLIST, photodiode: Path | None = None) -> None:
        self.netlist = Path(netlist)
        self.photodiode = Path(photodiode) if photodiode else self.netlist.with_name("photodiode.lib")
        self.ranges = feedback(self.netlist)
        #: nominal full-scale photocurrent of each range (A): out from Vref (30 mV) to the ADC's 5 V
        self.full_scale = [(V_ADC - 0.03) / r.value for r, _ in self.ranges]

    def run(self, control: str, edit=None, extra: str = "", read: tuple[str, ...] = ()) -> tuple[str, dict]:
        """Run ngspice in batch mode on the netlist (text passed through ``edit``) with a ``.control`` block in a
        scratch folder; returns (stdout, {name: array} of the wrdata files ``read``)."""
        with tempfile.TemporaryDirectory(prefix="frontend-") as d:
            tmp = Path(d)
            for lib in LIBS:
                src = self.photodiode if lib == "photodiode.lib" else self.netlist.with_name(lib)
                shutil.copyfile(src, tmp / lib)
            text = self.netlist.read_text(encoding="utf-8")
            (tmp / "frontend.cir").write_text(edit(text) if edit else text, encoding="utf-8")
            (tmp / "deck.cir").write_text(f"* analysis deck\n.include frontend.cir\n{extra}\n.control\n{control}\n"
                                          "quit 0\n.endc\n.end\n", encoding="utf-8")
            try:
                r = subprocess.run(["ngspice", "-b", "deck.cir"], cwd=tmp, capture_output=True, text=True,
                                   timeout=900)
            except (OSError, subprocess.TimeoutExpired) as e:
                raise SpiceError(f"ngspice did not run: {e}") from None
            missing = [name for name in read if not (tmp / name).is_file()]
            if r.returncode != 0 or missing:
                tail = [ln for ln in (r.stderr + r.stdout).splitlines() if "rror" in ln][-3:]
                raise SpiceError(f"ngspice failed (exit {r.returncode}): {' | '.join(tail) or 'no output file'}")
            return r.stdout, {name: np.loadtxt(tmp / name, ndmin=2) for name in read}

    # -- analyses ------------------------------------------------------------------------------------------------
    def dc(self, points: list[tuple[int, float]], node: str = "out", param: str = "iph") -> np.ndarray:
        """Operating points: v(node) in V for each (range index, photocurrent ``param`` in A)."""
        lines = []
        for k, (g, i) in enumerate(points):
            lines += [f"alterparam gain={g}", f"alterparam {param}={i:.9g}", "reset", "op", f"echo PT {k}",
                      f"print v({node})"]
        out, _ = self.run("\n".join(lines))
        vals = re.findall(rf"^PT (\d+)\s*\n\s*v\({node}\) = (\S+)", out, re.MULTILINE)
        if len(vals) != len(points):
            raise SpiceError(f"ngspice gave {len(vals)} of {len(points)} operating points")
        return np.array([float(v) for _, v in vals])

    def curves(self) -> tuple[np.ndarray, np.ndarray]:
        """DC curves: photocurrents (5, len(CURVE)) in A and outputs (5, len(CURVE)) in V."""
        iph = np.array([[f * fs for f in CURVE] for fs in self.full_scale])
        v = self.dc([(g, float(i)) for g in range(N_RANGES) for i in iph[g]])
        return iph, v.reshape(iph.shape)

    def loop_gain(self, gain: int) -> tuple[np.ndarray, np.ndarray]:
        """The loop gain T = A x beta of range ``gain``, broken at the op-amp's inverting input (an inductor keeps
        the DC loop closed; the pin's 6 pF + 3 pF stay on the feedback side): (frequency Hz, complex T)."""
        def edit(text: str) -> str:
            return text.replace("XU1 vref inn vdd 0 out mcp6001", "XU1 vref inn_op vdd 0 out mcp6001")

        extra = ("Lbrk inn inn_op 1T\nCinj inn_op vtest 1T\nVtest vtest 0 dc 0 ac 1\nCpin1 inn 0 6p\n"
                 "Cpin2 inn vref 3p\n")
        control = (f"alterparam gain={gain}\nalterparam iph=0\nreset\nac dec 40 10 100meg\n"
                   "let t = -v(inn)/v(inn_op)\nlet tre = real(t)\nlet tim = imag(t)\nwrdata ac.txt tre tim")
        d = self.run(control, edit=edit, extra=extra, read=("ac.txt",))[1]["ac.txt"]
        return d[:, 0], d[:, 1] + 1j * d[:, 3]

    def phase_margin(self, gain: int) -> tuple[float, float]:
        """(phase margin in deg, crossover frequency in Hz) of range ``gain``."""
        f, t = self.loop_gain(gain)
        mag = np.abs(t)
        k = int(np.argmax(mag < 1.0))
        if k == 0:
            raise SpiceError(f"range {gain}: the loop gain never crosses 1")
        w = (np.log(mag[k - 1])) / (np.log(mag[k - 1]) - np.log(mag[k]))
        fc = float(np.exp(np.log(f[k - 1]) + w * (np.log(f[k]) - np.log(f[k - 1]))))
        ph = np.degrees(np.unwrap(np.angle(t)))
        return float(180.0 + ph[k - 1] + w * (ph[k] - ph[k - 1])), fc

    def transient(self, params: dict[str, float], t_stop: float) -> tuple[np.ndarray, np.ndarray]:
        """v(out) over time after the parameters ``params`` (gain, gfrom, tsw, iph, istep, tstep): (t s, v V)."""
        alter = "\n".join(f"alterparam {k}={v:.9g}" for k, v in params.items())
        d = self.run(f"{alter}\nreset\ntran 0.5u {t_stop:.6g} 0 1u\nwrdata tran.txt v(out)",
                     read=("tran.txt",))[1]["tran.txt"]
        return d[:, 0], d[:, 1]

    def settle(self, params: dict[str, float], t0: float, t_after: float = 2.5e-3) -> tuple[float, float]:
        """(time to settle within 0.1 % of the final output, time constant to 63 % of the step), both in s after
        the switch at ``t0``."""
        t, v = self.transient(params, t0 + t_after)
        final, start = v[-1], float(np.interp(t0, t, v))
        out = np.abs(v - final) > 1e-3 * abs(final)
        settle = float(t[np.nonzero(out)[0][-1] + 1] - t0) if out.any() else 0.0
        frac = np.abs(v - start) >= 0.632 * abs(final - start)
        after = np.nonzero(frac & (t > t0))[0]
        tau = float(t[after[0]] - t0) if after.size else float("nan")
        return settle, tau

    def gain_settling(self, gain: int) -> dict[str, float]:
        """Settling of range ``gain`` at half its full scale after a switch from each neighbouring range (from the
        next higher one its output comes out of clipping)."""
        res = {}
        for frm in (gain - 1, gain + 1):
            if 0 <= frm < N_RANGES:
                res[f"from_{frm}"] = self.settle({"gain": gain, "gfrom": frm, "tsw": 2e-4,
                                                  "iph": 0.5 * self.full_scale[gain]}, 2e-4)[0]
        return res

    def source_settling(self, gain: int) -> tuple[float, float]:
        """(settle s, tau s) of range ``gain`` after light of half its full scale arrives (the source on)."""
        return self.settle({"gain": gain, "iph": 0.0, "istep": 0.5 * self.full_scale[gain], "tstep": 2e-4}, 2e-4)

    def noise_spectrum(self, gain: int) -> tuple[np.ndarray, np.ndarray]:
        """Output noise density at the ADC (node out), dark: (frequency Hz, V/rtHz). (ngspice's noise analysis
        wants an input source: a separate one, Vnz, as only the output's density is used.)"""
        d = self.run(f"alterparam gain={gain}\nalterparam iph=0\nreset\nnoise v(out) Vnz dec 40 0.1 10meg\n"
                     "setplot noise1\nwrdata noise.txt onoise_spectrum", read=("noise.txt",),
                     extra="Vnz nz 0 dc 0 ac 1\nRnz nz 0 1k\n")[1]["noise.txt"]
        return d[:, 0], d[:, 1]


def band_rms(f: np.ndarray, density: np.ndarray, f_lo: float, f_hi: float) -> float:
    """rms (V) of a noise density (V/rtHz at frequencies f) between f_lo and f_hi."""
    grid = np.geomspace(f_lo, f_hi, 2000)
    s = np.interp(np.log(grid), np.log(f), density ** 2)
    return float(math.sqrt(np.trapezoid(s, grid)))


def mean_of_samples_rms(f: np.ndarray, density: np.ndarray, n: int = NCONV, ts: float = SAMPLE_PERIOD_S,
                        f_lo: float = 1.0) -> float:
    """rms (V) of the mean of ``n`` samples ``ts`` apart of a noise of density (V/rtHz) at f, from its
    autocorrelation (the aliasing of the noise beyond the sampler's Nyquist frequency included), above f_lo."""
    grid = np.geomspace(f_lo, f[-1], 20000)
    s = np.interp(np.log(grid), np.log(f), density ** 2)
    lags = np.arange(-(n - 1), n)
    r = np.trapezoid(s[None, :] * np.cos(2 * np.pi * grid[None, :] * (lags[:, None] * ts)), grid, axis=1)
    return float(math.sqrt(max(np.sum((n - np.abs(lags)) * r) / n ** 2, 0.0)))


def sources_digest(netlist: Path = NETLIST) -> str:
    """sha256 of the netlist and its libraries: the table says which circuit it was made from."""
    h = hashlib.sha256()
    for p in (netlist, *(netlist.with_name(lib) for lib in LIBS)):
        h.update(p.name.encode() + b"\0" + p.read_bytes())
    return h.hexdigest()


def make_table(c: Circuit) -> dict:
    """The transfer table (see the module docstring) of circuit ``c``."""
    iph, v = c.curves()
    ranges = []
    for g, (r, cap) in enumerate(c.ranges):
        lin = (iph[g] >= 0.01 * c.full_scale[g]) & (iph[g] <= 0.9 * c.full_scale[g])
        slope = float(np.polyfit(iph[g][lin], v[g][lin], 1)[0]) if lin.sum() >= 2 else 0.0
        settle_src, tau_src = c.source_settling(g)
        gs = c.gain_settling(g)
        ranges.append({"index": g, "rf_ohm": r.value, "cf_farad": cap.value, "full_scale_a": c.full_scale[g],
                       "offset_v": float(v[g][0]), "slope_v_per_a": slope,
                       "v_max": float(np.max(v[g])), "v_min": float(np.min(v[g])),
                       "iph_a": [float(x) for x in iph[g]], "v_out": [round(float(x), 7) for x in v[g]],
                       "settle_gain_s": max(gs.values()), "settle_source_s": settle_src, "tau_s": tau_src})
    mon_fs = (V_ADC - 0.03) / MONITOR_RF
    imon = [f * mon_fs for f in CURVE]
    vmon = c.dc([(0, i) for i in imon], node="monitor", param="imon")
    monitor = {"node": "monitor", "rf_ohm": MONITOR_RF, "full_scale_a": mon_fs, "iph_a": imon,
               "v_out": [round(float(x), 7) for x in vmon]}
    return {"made_by": "python hardware/frontend/simulate.py --table", "netlist_sha256": sources_digest(c.netlist),
            "node": "out", "ranges": ranges, "monitor": monitor}


def figures(c: Circuit, table: dict | None = None) -> dict:
    """Phase margin, settling, noise per range and the dynamic range with each ADC (see ADCS)."""
    table = table or make_table(c)
    rows, floors = [], {name: [] for name in ADCS}
    for g in range(N_RANGES):
        pm, fc = c.phase_margin(g)
        f, dens = c.noise_spectrum(g)
        rt = table["ranges"][g]
        conv = band_rms(f, dens, 1.0, 1e6)
        reading = mean_of_samples_rms(f, dens)
        ads = band_rms(f, dens, 1.0, ADCS["ADS1115 16-bit"]["band_hz"])
        row = {"range": g, "rf_ohm": rt["rf_ohm"], "cf_farad": rt["cf_farad"], "phase_margin_deg": pm,
               "crossover_hz": fc, "settle_gain_s": rt["settle_gain_s"], "settle_source_s": rt["settle_source_s"],
               "noise_conversion_v": conv, "noise_reading_v": reading, "noise_ads1115_v": ads}
        for name, adc in ADCS.items():
            amp = ads if "band_hz" in adc else reading
            floor_v = math.hypot(amp, adc["noise_v"])
            top = min(rt["v_max"], adc["top_v"] + (rt["offset_v"] if adc.get("differential") else 0.0)) - rt["offset_v"]
            floors[name].append((top / rt["slope_v_per_a"], floor_v / rt["slope_v_per_a"]))
            row[f"decades_{name.split()[0]}"] = math.log10(top / floor_v)
        rows.append(row)
    dr = {name: {"full_scale_a": v[0][0], "floor_a": v[-1][1], "decades": math.log10(v[0][0] / v[-1][1])}
          for name, v in floors.items()}
    return {"ranges": rows, "dynamic_range": dr, "gain_settle_us": gain_settle_s() * 1e6}


def _eng(v: float) -> str:
    """10000 -> '10k', 1e-11 -> '10p'."""
    for scale, prefix in ((1e6, "M"), (1e3, "k"), (1.0, ""), (1e-6, "u"), (1e-9, "n"), (1e-12, "p")):
        if v >= scale * 0.999:
            return f"{v / scale:g}{prefix}"
    return f"{v:g}"


def print_figures(fig: dict) -> None:
    """The figures as docs/build-a-bench.md quotes them."""
    print("range  Rf      Cf      phase margin  crossover   settle gain  settle source  noise/conv  noise/reading"
          "  noise ADS1115  decades ATmega  decades ADS1115")
    for r in fig["ranges"]:
        print(f"{r['range']:>5}  {_eng(r['rf_ohm']):<6}  {_eng(r['cf_farad']):<6}  {r['phase_margin_deg']:>8.1f} deg"
              f"  {r['crossover_hz'] / 1e3:>6.1f} kHz  {r['settle_gain_s'] * 1e3:>8.2f} ms"
              f"  {r['settle_source_s'] * 1e3:>10.2f} ms  {r['noise_conversion_v'] * 1e6:>7.1f} uV"
              f"  {r['noise_reading_v'] * 1e6:>9.1f} uV  {r['noise_ads1115_v'] * 1e6:>10.1f} uV"
              f"  {r['decades_ATmega328P']:>14.2f}  {r['decades_ADS1115']:>15.2f}")
    print(f"the firmware waits {fig['gain_settle_us']:.0f} us after a gain switch (GAIN_SETTLE_US)")
    for name, d in fig["dynamic_range"].items():
        print(f"dynamic range over the five ranges, {name}: {d['full_scale_a']:.3g} A full scale on range 0 / "
              f"{d['floor_a']:.3g} A noise floor on range 4 = {d['decades']:.2f} decades")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 epilog="examples: python hardware/frontend/simulate.py --table; "
                                        "python hardware/frontend/simulate.py --figures",
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--table", action="store_true", help="write the transfer table (JSON) the simulator reads")
    ap.add_argument("--out", type=Path, default=TABLE, help=f"where --table writes (default {TABLE.relative_to(REPO)})")
    ap.add_argument("--figures", action="store_true", help="print phase margin, settling, noise, dynamic range")
    ap.add_argument("--netlist", type=Path, default=NETLIST, help="another netlist (its .lib files beside it)")
    ap.add_argument("--photodiode", type=Path, help="another photodiode model (subckt photodiode, pins anode cathode)")
    a = ap.parse_args(argv)
    if not (a.table or a.figures):
        ap.print_usage(sys.stderr)
        print("simulate.py: error: give --table and/or --figures", file=sys.stderr)
        return 2
    problem = ngspice_problem()
    for p in (a.netlist, a.photodiode):
        if p is not None and not Path(p).is_file():
            problem = f"{p}: no such file"
    if problem:
        print(f"simulate.py: {problem}", file=sys.stderr)
        return 2
    try:
        c = Circuit(a.netlist, a.photodiode)
        table = make_table(c)
        if a.table:
            a.out.parent.mkdir(parents=True, exist_ok=True)
            a.out.write_text(json.dumps(table, indent=1) + "\n", encoding="utf-8")
            print(f"wrote {a.out}")
        if a.figures:
            print_figures(figures(c, table))
    except (SpiceError, ValueError) as e:
        print(f"simulate.py: {e}", file=sys.stderr)
        return 2
    except OSError as e:  # a library missing beside the netlist, an unwritable --out
        print(f"simulate.py: {e.filename}: {e.strerror}", file=sys.stderr)
        return 2
    return 0


if __name__ == "__main__":
    sys.exit(main())
