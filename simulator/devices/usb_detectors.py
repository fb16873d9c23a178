"""The simulated world's side of the detectors that are not the board's: an Ocean Insight spectrometer
(``[detector] type = "seabreeze"``) and a Thorlabs PM100 power meter (``type = "pm100"``), served on the bench's
``usb`` pseudo-terminal to their stand-ins (:mod:`simulator.devices.seabreeze_standin`,
:mod:`simulator.devices.pm100_standin`), which play the libraries the drivers call (python-seabreeze, pyvisa).

These are stand-ins, not the devices: a real spectrometer speaks Ocean Insight's USB protocol to libseabreeze and
a real meter SCPI over USB-TMC; neither is emulated byte for byte. What is the world's is the reading: the arms'
physical angles at the middle of the integration, the sample in place (the board's ``SAMPLE``), the source (the
board's ``SOURCE`` pin), noise and saturation (:class:`simulator.world.physics.BenchPhysics`), and the time a
reading takes on the simulated clock.

**Spectrometer wire** (one line a command, one reply line; ``error: text`` on a bad command)::

    INFO?          -> INFO model=... serial=... max=<counts> tmin_us=<us> tmax_us=<us> dark_pixels=0|1
    WL?            -> WL <nm>,<nm>,...
    INT <us>       -> ok                     (integration time, microseconds)
    SPECTRUM       -> SPECTRUM dark=<counts> <c1>,<c2>,...   (one scan; the electrical dark pixels' mean)

**Power meter**: the subset of the PM100's SCPI the driver uses (``*IDN?``, ``SYST:SENS:IDN?``,
``SENS:CORR:WAV``, ``SENS:AVER:COUN``, ``SENS:POW:RANG:AUTO``, ``SENS:POW:RANG``, ``CONF:POW``, ``READ?``,
``MEAS:POW?``, ``SYST:ERR?``); queries get one reply line, settings none (as SCPI). One count of the physics is
:data:`WATTS_PER_COUNT` watts; a power above the fixed range's upper limit reads :data:`OVER_RANGE`.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable

import numpy as np

from simulator.config import BenchConfig
from simulator.world.clock import Paced, SimClock
from simulator.world.physics import BenchPhysics

log = logging.getLogger("simulator.usb")

__all__ = ["UsbDetector", "WATTS_PER_COUNT", "OVER_RANGE", "PM100_RANGES_W", "PM100_SAMPLE_S", "RANGE_NOISE",
           "SPECTROMETER_LIMITS_US"]

#: Watts of one count of the simulated physics (a gain-1 count at the reference integration time).
WATTS_PER_COUNT = 1e-9
#: What the simulated meter reads above its fixed range (SCPI's overflow value).
OVER_RANGE = 9.9e37
#: The simulated PM100's power ranges (upper limits, W): decades from 5 nW to 50 mW.
PM100_RANGES_W = tuple(5e-9 * 10.0 ** k for k in range(8))
#: Noise of one sample of the simulated meter, relative to its range's upper limit.
RANGE_NOISE = 1e-4
#: Time of one averaged sample of the simulated meter (s); ``SENS:AVER:COUN n`` reads for n of them.
PM100_SAMPLE_S = 3e-3
#: Integration time limits of the simulated spectrometer (microseconds), as a USB2000+'s.
SPECTROMETER_LIMITS_US = (1000, 65_000_000)
#: Electrical dark pixels of the simulated spectrometer (their mean is what dark-count correction subtracts).
_DARK_PIXELS = 8


class UsbDetector(Paced):
    """Interpreter of the ``usb`` port: the spectrometer wire or the meter's SCPI (by ``[detector].type``).

    ``arm_angles(t)``: the arms' physical (theta_i, theta_o) in degrees at simulated time ``t``."""

    def __init__(self, cfg: BenchConfig, clock: SimClock, physics: BenchPhysics,
                 arm_angles: Callable[[float | None], tuple[float, float]]) -> None:
        self.cfg = cfg
        self.kind = cfg.detector.type
        self.clock = clock
        self.physics = physics
        self.arm_angles = arm_angles
        self._buf = bytearray()
        self._wait = 0.0
        self.t_us = int(round(cfg.detector.integration_time_s * 1e6))
        self._switches_seen = 0
        self.wavelength_nm = 633.0
        self.averages = 1
        self.auto_range = True
        self.range_w = PM100_RANGES_W[-1]
        self.errors: list[str] = []

    # -- bytes ------------------------------------------------------------------------------------------------
    def process(self, data: bytes) -> bytes:
        """Feed received bytes; the reply bytes of every complete line. Never raises."""
        self._buf += data
        out = bytearray()
        while not self._wait:
            j = self._buf.find(b"\n")
            if j < 0:
                if len(self._buf) > 4096:
                    self._buf.clear()
                break
            text = bytes(self._buf[:j]).decode("ascii", errors="replace").strip()
            del self._buf[: j + 1]
            if not text:
                continue
            try:
                reply = self._spectrometer(text) if self.kind == "seabreeze" else self._scpi(text)
            except Exception:  # pragma: no cover - a bug: answered, never raised into the port thread
                log.exception("usb device failure on %r", text)
                reply = "error: internal"
            if reply is not None:
                out += (reply + "\n").encode("ascii")
        return bytes(out)

    def _angles(self, duration_s: float) -> tuple[float, float]:
        """The arms' angles at the middle of a reading of ``duration_s``."""
        return self.arm_angles(self.clock.now() + duration_s / 2)

    # -- the spectrometer ---------------------------------------------------------------------------------------
    def _spectrometer(self, text: str) -> str:
        det = self.physics.detector
        word, _, arg = text.partition(" ")
        if word == "INFO?":
            return (f"INFO model=USB2000PLUS-standin serial=SIM-SB-0001 max={det.max_code:g} "
                    f"tmin_us={SPECTROMETER_LIMITS_US[0]} tmax_us={SPECTROMETER_LIMITS_US[1]} dark_pixels=1")
        if word == "WL?":
            return "WL " + ",".join(f"{w:.6g}" for w in np.asarray(det.wavelengths_nm))
        if word == "INT":
            try:
                t_us = int(arg)
            except ValueError:
                return "error: INT needs an integer number of microseconds"
            if not SPECTROMETER_LIMITS_US[0] <= t_us <= SPECTROMETER_LIMITS_US[1]:
                return "error: integration time out of range"
            self.t_us = t_us
            return "ok"
        if word == "SPECTRUM":
            t = self.t_us * 1e-6
            det.integration_time_s = t
            ti, to = self._angles(t)
            codes, _ = self.physics.read(ti, to, source_on=self.physics.source_on)
            if self.physics.source_switches != self._switches_seen:  # a free-running scan began before the
                self._switches_seen = self.physics.source_switches  # switch: half of it saw the old state
                old, _ = self.physics.read(ti, to, source_on=not self.physics.source_on)
                codes = np.round((codes + old) / 2)
            noise = self.physics.noise_rms() / math.sqrt(_DARK_PIXELS)
            dark = self.physics.dark_offset + self.physics.detector.gain * self.physics.input_offset \
                + noise * float(self.physics.rng.standard_normal())
            self._advance(t)
            return f"SPECTRUM dark={dark:.3f} " + ",".join(str(int(v)) for v in codes[0])
        return f"error: unknown command {word!r}"

    # -- the power meter ----------------------------------------------------------------------------------------
    def _power_w(self) -> float:
        """One averaged reading (W) at the present arms, sample and source."""
        n = self.averages
        ph = self.physics
        ti, to = self._angles(n * PM100_SAMPLE_S)
        s = float(ph.expected_signal(ti, to, ph.source_on, ph.detector.ref_integration_time_s)[..., 0])
        x = s + ph.dark_offset + ph.input_offset  # the offset: the head's dark current, what a dark reads
        rng = next((r for r in PM100_RANGES_W if x * WATTS_PER_COUNT <= r), None) if self.auto_range \
            else self.range_w
        self._advance(n * PM100_SAMPLE_S)
        if rng is None or x * WATTS_PER_COUNT > rng:
            return OVER_RANGE
        # noise of one sample: RANGE_NOISE of the range (the amplifier and converter) and the light's shot noise
        floor = RANGE_NOISE * rng / WATTS_PER_COUNT
        sd = math.sqrt(floor ** 2 + (max(s, 0.0) / ph.electrons_per_count if ph.shot_noise else 0.0))
        return max(x + sd / math.sqrt(n) * float(ph.rng.standard_normal()), 0.0) * WATTS_PER_COUNT

    def _scpi(self, text: str) -> str | None:
        head, _, arg = text.partition(" ")
        h = head.upper()
        for long, short in (("SENSE", "SENS"), ("CORRECTION", "CORR"), ("WAVELENGTH", "WAV"), ("WAVE", "WAV"),
                            ("AVERAGE", "AVER"), ("COUNT", "COUN"), ("POWER", "POW"), ("RANGE", "RANG"),
                            ("MEASURE", "MEAS"), ("CONFIGURE", "CONF"), ("SYSTEM", "SYST"), ("SENSOR", "SENS"),
                            ("ERROR", "ERR"), (":DC", "")):
            h = h.replace(long, short)
        h = h.lstrip(":")
        if h == "*IDN?":
            return "Thorlabs,PM100USB-standin,SIM-PM-0001,1.0.0"
        if h == "SYST:SENS:IDN?":
            return "S120C-standin,SIM-HEAD-0001,01-Jan-2026,1,18,289"
        if h == "SYST:ERR?":
            return self.errors.pop(0) if self.errors else '0,"No error"'
        if h in ("READ?", "MEAS:POW?", "MEAS?"):
            return f"{self._power_w():.6E}"
        if h in ("CONF:POW", "*CLS", "*RST"):
            return None
        if h == "SENS:CORR:WAV?":
            return f"{self.wavelength_nm:.6E}"
        if h == "SENS:AVER:COUN?":
            return str(self.averages)
        if h == "SENS:POW:RANG:AUTO?":
            return "1" if self.auto_range else "0"
        if h in ("SENS:POW:RANG?", "SENS:POW:RANG:UPP?"):
            if arg.strip().upper().startswith("MAX"):
                return f"{PM100_RANGES_W[-1]:.6E}"
            if arg.strip().upper().startswith("MIN"):
                return f"{PM100_RANGES_W[0]:.6E}"
            return f"{self.range_w:.6E}"
        try:
            if h == "SENS:CORR:WAV":
                self.wavelength_nm = min(max(float(arg), 400.0), 1100.0)
                return None
            if h == "SENS:AVER:COUN":
                self.averages = min(max(int(float(arg)), 1), 100_000)
                return None
            if h == "SENS:POW:RANG:AUTO":
                self.auto_range = arg.strip().upper() in ("1", "ON")
                return None
            if h in ("SENS:POW:RANG", "SENS:POW:RANG:UPP"):
                want = float(arg)
                self.range_w = next((r for r in PM100_RANGES_W if r >= want * (1 - 1e-9)), PM100_RANGES_W[-1])
                self.auto_range = False
                return None
        except ValueError:
            self.errors.append('-222,"Data out of range"')
            return None
        self.errors.append('-113,"Undefined header"')
        return None
