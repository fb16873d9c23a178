"""The detector's amplifier as the simulator sees it: the circuit's own transfer, not a formula.

``hardware/frontend/transfer.json`` is made by ngspice from the netlist a lab builds
(``python hardware/frontend/simulate.py --table``; tests/test_frontend_spice.py regenerates it and checks that the
committed one matches): for each of the five ranges the DC curve from photocurrent (A) to the ADC input (V) up to
and beyond clipping at the op-amp's real swing, and the time the output takes to settle to 0.1 % after a gain or a
source switch. Reading the table needs no ngspice.

The photocurrent scale (:data:`AMPS_PER_COUNT`): the physics (:mod:`simulator.world.physics`) counts its signal
in ADC counts at gain 1, summed over a repeat's conversions; an ideal range 0 (10 k) turns one count per
conversion (one LSB of the board's 10-bit ADC on 5 V, 4.888 mV) into 4.888 mV / 10 k = 0.489 uA. So a bench file's
``source_power`` of 1e6 counts per (1/sr sr) at 80 conversions is 12,500 counts per conversion, 6.1 mA of
photocurrent per unit of f_r cos(theta_o) Omega: with a silicon photodiode's 0.4 A/W over a halogen lamp's band,
15 mW of light on the sample, what a 1 W white LED or a 20 W halogen lamp focused to a 10 mm spot gives.
"""

from __future__ import annotations

import json
import math
import os
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["TABLE", "AMPS_PER_COUNT", "ADC_LSB_V", "SAMPLE_PERIOD_S", "FrontEnd", "load_frontend"]

TABLE = Path(__file__).resolve().parents[2] / "hardware" / "frontend" / "transfer.json"
#: the board's ADC: 10 bits on AVcc = 5 V (the firmware's truncating converter: floor(1023 V / 5 V))
ADC_LSB_V = 5.0 / 1023
#: the firmware's conversion period (firmware/detector/src/config.h SAMPLE_PERIOD_US)
SAMPLE_PERIOD_S = 125e-6
#: photocurrent (A) of one count per conversion at gain 1 (an ideal 10 k range): see the module docstring
AMPS_PER_COUNT = ADC_LSB_V / 10e3


@dataclass(frozen=True)
class FrontEnd:
    """The transfer table: per range (index 0..4), photocurrents ``iph`` (A) and outputs ``v`` (V) of its DC
    curve, and its settling times after a gain or a source switch (s)."""

    iph: tuple[np.ndarray, ...]
    v: tuple[np.ndarray, ...]
    settle_gain_s: tuple[float, ...]
    settle_source_s: tuple[float, ...]
    path: Path
    #: the monitor photodiode's amplifier (node monitor, the ADC's channel 1): (photocurrents A, outputs V)
    monitor: tuple[np.ndarray, np.ndarray] | None = None

    @classmethod
    def read(cls, path: Path = TABLE) -> FrontEnd:
        """Read a table written by ``simulate.py --table``; ValueError naming the file and what is wrong."""
        try:
            doc = json.loads(Path(path).read_text(encoding="utf-8"))
            ranges = sorted(doc["ranges"], key=lambda r: r["index"])
            iph = tuple(np.asarray(r["iph_a"], dtype=float) for r in ranges)
            v = tuple(np.asarray(r["v_out"], dtype=float) for r in ranges)
            sg = tuple(float(r["settle_gain_s"]) for r in ranges)
            ss = tuple(float(r["settle_source_s"]) for r in ranges)
            mon = doc.get("monitor")
            monitor = (np.asarray(mon["iph_a"], dtype=float), np.asarray(mon["v_out"], dtype=float)) if mon else None
        except OSError as e:
            raise ValueError(f"{path}: cannot read the amplifier's transfer table ({e.strerror}); make it with "
                             "python hardware/frontend/simulate.py --table") from None
        except (ValueError, KeyError, TypeError) as e:
            raise ValueError(f"{path}: not a transfer table of simulate.py --table ({e})") from None
        bad = [a.size < 2 or a.size != b.size or np.any(np.diff(a) <= 0) for a, b in zip(iph, v, strict=True)]
        if not ranges or any(bad):
            raise ValueError(f"{path}: each range needs increasing photocurrents with one output each")
        return cls(iph, v, sg, ss, Path(path), monitor)

    @property
    def n_ranges(self) -> int:
        return len(self.iph)

    def output_v(self, iph_a, gain_index) -> np.ndarray:
        """The ADC input (V) for photocurrents ``iph_a`` (A, any shape) on range(s) ``gain_index`` (0..4,
        broadcast with ``iph_a``): the circuit's DC curve, linear between its points, flat beyond its last (the
        op-amp clips) and continued along its first segment below 0 A (light taken away, e.g. a chopped
        ambient's share), never under its lowest output (the op-amp's bottom swing)."""
        iph, g = np.broadcast_arrays(np.asarray(iph_a, dtype=float), np.asarray(gain_index, dtype=int))
        out = np.empty(iph.shape)
        for k in np.unique(g):
            if not 0 <= k < self.n_ranges:
                raise ValueError(f"gain index {k} is not a range of the amplifier (0..{self.n_ranges - 1})")
            m = g == k
            x, y = self.iph[k], self.v[k]
            slope = (y[1] - y[0]) / (x[1] - x[0])
            vals = np.interp(iph[m], x, y)
            below = iph[m] < x[0]
            vals[below] = np.maximum(y[0] + slope * (iph[m][below] - x[0]), self.v_floor(k))
            out[m] = vals
        return out

    def monitor_v(self, imon_a) -> np.ndarray:
        """The monitor amplifier's output (V, node ``monitor``, the ADC's channel 1) for the monitor photodiode's
        photocurrents ``imon_a`` (A, any shape): its DC curve, flat beyond its last point (clipped)."""
        if self.monitor is None:
            raise ValueError(f"{self.path}: the table has no monitor amplifier (made before it was in the netlist)")
        x, y = self.monitor
        return np.interp(np.asarray(imon_a, dtype=float), x, y)

    def v_floor(self, gain_index: int) -> float:
        """The lowest output of range ``gain_index`` (V): its dark output less the op-amp's headroom to the
        ground rail, taken as the curve's lowest point or 10 mV, whichever is lower."""
        return min(float(np.min(self.v[gain_index])), 0.010)

    def adc_input_mv(self, iph_a, gain_index) -> np.ndarray:
        """:meth:`output_v` in mV (what the emulated board's ADC reads)."""
        return 1e3 * self.output_v(iph_a, gain_index)

    def residual(self, t_since_s, gain_index: int, kind: str = "gain") -> np.ndarray:
        """Fraction of a step not yet settled ``t_since_s`` seconds after a ``kind`` ("gain" or "source") switch
        onto range ``gain_index``: exp(-t / tau) with tau such that 0.1 % is reached at the table's settling time."""
        settle = (self.settle_gain_s if kind == "gain" else self.settle_source_s)[gain_index]
        tau = max(settle, 1e-9) / math.log(1000.0)
        return np.exp(-np.maximum(np.asarray(t_since_s, dtype=float), 0.0) / tau)

    def reading_counts(self, signal_counts, gain_index, integration_time_s: float, extra_a=0.0) -> np.ndarray:
        """A repeat's sum of conversions (counts, not quantised) for the physics' signal ``signal_counts`` (counts
        at gain 1 summed over the repeat, any shape) on range(s) ``gain_index``: photocurrent (AMPS_PER_COUNT per
        count per conversion) plus ``extra_a`` (A, broadcast: light that is not the source's, e.g. the room's),
        the circuit's output, back to counts of the 10-bit ADC summed over the repeat."""
        nconv = max(integration_time_s / SAMPLE_PERIOD_S, 1e-9)
        iph = np.asarray(signal_counts, dtype=float) / nconv * AMPS_PER_COUNT + np.asarray(extra_a, dtype=float)
        return nconv * self.output_v(iph, gain_index) / ADC_LSB_V


def load_frontend(path: str | None = None) -> FrontEnd:
    """The transfer table at ``path``, else at ``$GONIO_FRONTEND_TABLE`` (another circuit's table, e.g. a scratch
    copy of the netlist's, made with ``simulate.py --table --netlist ... --out ...``), else the committed one; each
    file read once."""
    return _load(str(path or os.environ.get("GONIO_FRONTEND_TABLE") or TABLE))


@lru_cache(maxsize=8)
def _load(path: str) -> FrontEnd:
    return FrontEnd.read(Path(path))
