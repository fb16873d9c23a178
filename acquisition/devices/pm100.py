"""Thorlabs PM100-series power meters through pyvisa (SCPI over USB-TMC): ``[detector] type = "pm100"``.

``pip install 'gonio-brdf[pm100]'`` installs pyvisa; it needs a VISA library underneath (NI-VISA or Keysight
IO Libraries, or ``pip install pyvisa-py pyusb`` for a pure-Python one). The driver speaks the meter's SCPI:

- ``[detector].resource`` names the VISA resource (``USB0::0x1313::0x8078::P0012345::INSTR``); without it the first
  Thorlabs resource (vendor id 0x1313) found is used. ``*IDN?`` and ``SYST:SENS:IDN?`` identify the meter and
  its sensor head: a meter with no head answers with one line saying to plug one in;
- ``CONF:POW`` and ``SENS:CORR:WAV`` (nm): the wavelength correction, ``[detector].wavelength_nm`` or else the
  centroid of the bench's source as the sensor's band sees it (``[bench].source_spectrum`` x
  ``[detector].responsivity``);
- averaging (``SENS:AVER:COUN n``) is the integration time: ``n`` samples of :data:`SAMPLE_S` each;
- ranges: without ``[detector].gains`` the meter's own auto-range (``SENS:POW:RANG:AUTO ON``); with gains, fixed
  ranges on the auto-ranging's gain ladder: gain ``g`` is the range whose upper limit is the top range / ``g``
  (``SENS:POW:RANG``, read back), and a reading is ``P * COUNTS_PER_WATT * g``, so that every range saturates at
  the same count (the top range's) and auto-ranging converts between them as between an amplifier's gains;
- a reading (``READ?``, watts) becomes counts (:data:`COUNTS_PER_WATT`: one count is a nanowatt at gain 1), the
  photodiode's quantity: relative calibration divides it by the white reference's, absolute calibration takes
  ``[calibration].source_power`` in the same counts. ``n`` repeats are ``n`` readings, averaged;
- over-range (SCPI's overflow value 9.9E37, or more than the range's upper limit) is a saturated repeat on a
  fixed range below the top (auto-ranging then takes a less sensitive range), and one clear line on the top range
  or in the meter's own auto-range;
- a dark turns the source off (:class:`acquisition.devices.board.BoardBacked`): the board's pin or the operator.

pyvisa's ``ResourceManager`` is passed in as ``resource_manager`` (a callable; ``pyvisa.ResourceManager`` when
None), so the tests hand the driver pyvisa-sim's (``ResourceManager("pm100-sim.yaml@sim")``) or the simulator's
stand-in (:mod:`simulator.devices.pm100_standin`).
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import numpy as np

from acquisition.calibration import Reading
from acquisition.devices.board import BoardBacked
from acquisition.devices.serial_link import SerialLink
from acquisition.errors import DeviceError

log = logging.getLogger("acquisition.pm100")

__all__ = ["Pm100Detector", "import_pyvisa", "COUNTS_PER_WATT", "SAMPLE_S", "INSTALL_HINT", "band_centroid_nm"]

INSTALL_HINT = "pip install 'gonio-brdf[pm100]' (pyvisa; and a VISA library: NI-VISA, or pip install pyvisa-py pyusb)"
#: Counts per watt of a reading at gain 1: one count is a nanowatt.
COUNTS_PER_WATT = 1e9
#: Time of one averaged sample (s): about 3 ms on the PM100D/PM100USB (check your model's manual).
SAMPLE_S = 3e-3
#: Readings at or above this are SCPI's overflow (over-range).
OVERFLOW = 9.0e37
#: Thorlabs' USB vendor id in VISA resource names.
THORLABS_VENDOR = "0x1313"


def import_pyvisa() -> Callable[[], Any]:
    """``pyvisa.ResourceManager``; a :class:`DeviceError` naming what to install when pyvisa is missing."""
    try:
        import pyvisa  # type: ignore[import-not-found]
    except ImportError as e:
        raise DeviceError(f'[detector] type = "pm100" needs pyvisa, which is not installed ({e}): {INSTALL_HINT}'
                          ) from None
    return pyvisa.ResourceManager


def band_centroid_nm(weights: Any) -> float:
    """The centroid (nm) of a photodiode band's weights on :data:`reconstruction.schema.optics.BAND_NM`."""
    from reconstruction.schema.optics import BAND_NM

    w = np.asarray(weights, dtype=float)
    return float(w @ BAND_NM / w.sum())


class Pm100Detector(BoardBacked):
    """A Thorlabs PM100 with a photodiode head; see the module docstring. Times in seconds, readings in counts
    (:data:`COUNTS_PER_WATT`)."""

    type = "pm100"
    wavelengths_nm = None
    channels = ["value"]

    def __init__(self, resource_manager: Callable[[], Any], resource: str | None, integration_time_s: float,
                 wavelength_nm: float, gains: tuple[float, ...] | None = None, start_gain: float | None = None,
                 link: SerialLink | None = None, source_off: str = "auto", timeout_s: float = 5.0) -> None:
        super().__init__(link, source_off, name="Thorlabs PM100")
        self.rm_factory = resource_manager
        self.resource = resource
        self.integration_time_s = integration_time_s
        self.wavelength_nm = wavelength_nm
        self.gains = gains
        self.start_gain = start_gain if start_gain is not None else (min(gains) if gains else None)
        self.gain: float | None = None
        self.timeout_s = timeout_s
        self.rm: Any = None
        self.inst: Any = None
        self.idn = ""
        self.sensor = ""
        self.top_range_w = float("inf")
        self.range_w = float("inf")
        self.averages = 1
        self.saturation = float("inf")
        self._found: list[str] = []

    # -- the SCPI dialogue ---------------------------------------------------------------------------------------
    def _query(self, cmd: str) -> str:
        try:
            return str(self.inst.query(cmd)).strip()
        except Exception as e:  # noqa: BLE001 - pyvisa's VisaIOError (a timeout, a vanished device), in one line
            raise DeviceError(f"{self.name} {self.resource}: no answer to {cmd!r} ({e}); is it still connected?"
                              ) from None

    def _write(self, cmd: str) -> None:
        try:
            self.inst.write(cmd)
        except Exception as e:  # noqa: BLE001
            raise DeviceError(f"{self.name} {self.resource}: cannot send {cmd!r} ({e}); is it still connected?"
                              ) from None

    def _number(self, cmd: str) -> float:
        text = self._query(cmd)
        try:
            return float(text.split(",")[0])
        except ValueError:
            raise DeviceError(f"{self.name} {self.resource}: {cmd!r} answered {text!r}, not a number") from None

    def _check_errors(self, after: str) -> None:
        """``SYST:ERR?`` until "no error": a refused setting is one line naming it."""
        for _ in range(10):
            e = self._query("SYST:ERR?")
            if e.split(",")[0].strip() in ("0", "+0"):
                return
            raise DeviceError(f"{self.name} {self.resource}: the meter refused {after}: {e}")

    def _find_resource(self) -> str:
        try:
            found = list(self.rm.list_resources())
        except Exception as e:  # noqa: BLE001
            raise DeviceError(f"{self.name}: pyvisa cannot list instruments ({e}); {INSTALL_HINT}") from None
        self._found = found
        if self.resource:
            return self.resource
        meters = [r for r in found if THORLABS_VENDOR in r.lower() or "pm100" in r.lower()]
        if not meters:
            raise DeviceError(f"{self.name}: no Thorlabs power meter found by pyvisa (resources: "
                              f"{', '.join(found) or 'none'}): plug it in by USB (and check the VISA library and the "
                              "device's permissions), or give [detector].resource")
        return meters[0]

    def connect(self) -> None:
        """Open the meter, check its sensor head, set power mode, wavelength, averaging and ranges; learn the
        board's services and put the sample in place."""
        try:
            self.rm = self.rm_factory()
        except Exception as e:  # noqa: BLE001 - no VISA library underneath pyvisa
            raise DeviceError(f"{self.name}: pyvisa has no VISA library to use ({e}); {INSTALL_HINT}") from None
        self.resource = self._find_resource()
        try:
            self.inst = self.rm.open_resource(self.resource)
        except Exception as e:  # noqa: BLE001
            raise DeviceError(f"{self.name}: cannot open {self.resource} ({e}): plug the meter in, or check "
                              f"[detector].resource (resources: {', '.join(self._found) or 'none'})") from None
        self.inst.timeout = self.timeout_s * 1000.0
        self.inst.read_termination = "\n"
        self.inst.write_termination = "\n"
        self.idn = self._query("*IDN?")
        if "thorlabs" not in self.idn.lower():
            raise DeviceError(f"{self.name}: {self.resource} answers *IDN? with {self.idn!r}: not a Thorlabs power "
                              f"meter; check [detector].resource (resources: {', '.join(self._found) or 'none'})")
        self.sensor = self._query("SYST:SENS:IDN?")
        fields = [f.strip() for f in self.sensor.split(",")]
        flags = int(fields[5]) if len(fields) > 5 and fields[5].lstrip("+-").isdigit() else 1
        if not fields[0] or "no sensor" in self.sensor.lower() or not flags & 1:
            raise DeviceError(f"{self.name} {self.resource}: no power sensor head on the meter (it answers "
                              f"{self.sensor!r}): plug a photodiode sensor in, then start again")
        self._write("CONF:POW")
        self._write(f"SENS:CORR:WAV {self.wavelength_nm:.6g}")
        self._check_errors(f"the wavelength correction {self.wavelength_nm:g} nm")
        self.set_integration_time(self.integration_time_s)
        self._write("SENS:POW:RANG:AUTO ON")
        self.top_range_w = self._number("SENS:POW:RANG? MAX")
        self.saturation = self.top_range_w * COUNTS_PER_WATT
        if self.gains:
            self._write("SENS:POW:RANG:AUTO OFF")
            self.set_gain(self.start_gain)  # type: ignore[arg-type]
        self._check_errors("its settings")
        self.connect_board()
        log.info("%s %s: %s, sensor %s, wavelength %g nm, averaging %d (%g s), %s", self.name, self.resource,
                 self.idn, fields[0], self.wavelength_nm, self.averages, self.integration_time_s,
                 "its own auto-range" if not self.gains else f"fixed ranges from {self.top_range_w:g} W")
        self.set_sample("TARGET")

    def close(self) -> None:
        for obj in (self.inst, self.rm):
            try:
                if obj is not None:
                    obj.close()
            except Exception:  # pragma: no cover - closing a vanished device
                pass
        self.inst = self.rm = None

    # -- settings -----------------------------------------------------------------------------------------------
    def set_integration_time(self, seconds: float) -> float:
        """Averaging ``SENS:AVER:COUN n`` with ``n = seconds / SAMPLE_S`` (at least 1); returns ``n * SAMPLE_S``."""
        n = max(1, int(round(seconds / SAMPLE_S)))
        self._write(f"SENS:AVER:COUN {n}")
        self.averages = int(self._number("SENS:AVER:COUN?"))
        self.integration_time_s = self.averages * SAMPLE_S
        return self.integration_time_s

    def set_gain(self, gain: float) -> float:
        """The fixed range whose upper limit is the top range / ``gain`` (``SENS:POW:RANG``); returns the gain of
        the range the meter reports (top range / its upper limit)."""
        self._write(f"SENS:POW:RANG {self.top_range_w / gain:.6E}")
        self.range_w = self._number("SENS:POW:RANG?")
        if not self.range_w > 0:
            raise DeviceError(f"{self.name} {self.resource}: range {self.range_w!r} W after SENS:POW:RANG")
        self.gain = self.top_range_w / self.range_w
        return self.gain

    # -- readings -----------------------------------------------------------------------------------------------
    def _read(self, n: int) -> Reading:
        g = self.gain if self.gains else 1.0
        vals = np.empty(n)
        sat = 0
        for k in range(n):
            p = self._number("READ?")
            over = p >= OVERFLOW or (self.gains is not None and p > self.range_w * (1 + 1e-6))
            if over:
                if not self.gains or self.gain is None or self.gain <= 1.0 + 1e-9:
                    raise DeviceError(f"{self.name} {self.resource}: over range: more light than the sensor's top "
                                      f"range ({self.top_range_w:g} W); reduce the source power or add a neutral "
                                      "density filter")
                sat += 1
                vals[k] = self.saturation
            else:
                vals[k] = p * COUNTS_PER_WATT * g  # type: ignore[operator]
        std = np.array([vals.std(ddof=1)]) if n > 1 else np.zeros(1)
        return Reading(np.array([vals.mean()]), std, n, sat)

    def read(self, n: int) -> Reading:
        """``n`` readings (``READ?``, each averaged over the integration time) with the source on, in counts."""
        return self._read(n)

    def dark(self, n: int) -> Reading:
        """``n`` readings with the source off (the board's pin or the operator)."""
        return self.with_source_off(self._read, n)

    def describe(self) -> dict[str, Any]:
        """Type, identity, sensor, wavelength (nm), averaging, integration time (s), saturation (counts), range."""
        return {"type": self.type, "idn": self.idn, "sensor": self.sensor, "channels": 1,
                "wavelength_nm": self.wavelength_nm, "averages": self.averages,
                "integration_time_s": self.integration_time_s, "saturation": self.saturation,
                "range": "auto" if not self.gains else f"{self.range_w:g} W", **self.board_description()}
