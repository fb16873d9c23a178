"""Ocean Insight (Ocean Optics) spectrometers through python-seabreeze: ``[detector] type = "seabreeze"``.

``pip install 'gonio-brdf[seabreeze]'`` installs the library (on Linux, ``seabreeze_os_setup`` once installs its
udev rules so that the device can be opened without root). The driver uses only the library's documented calls
(``seabreeze.spectrometers``: ``list_devices()``, ``Spectrometer.from_serial_number(serial)`` which takes the
first device when ``serial`` is None, ``.wavelengths()``, ``.intensities(correct_dark_counts,
correct_nonlinearity)``, ``.integration_time_micros(us)``, ``.integration_time_micros_limits``,
``.max_intensity``, ``.serial_number``, ``.model``, ``.f.shutter``, ``.close()``, ``SeaBreezeError``):

- ``[detector].serial_number`` picks the device (else the first one found); the wavelengths (nm) become the slice's
  channels (``"532.1nm"``), so the reconstruction's spectral-to-RGB path takes them as it takes the board
  spectrometer's;
- the integration time (s) is set in microseconds within the device's limits, so auto-ranging walks its ladder
  over the device's own range; the saturation is the device's maximum intensity (or ``[detector].saturation`` if
  lower); after a change one scan is discarded (many models deliver one scan begun at the old time), and so after
  the source is switched (for a dark and back: the scan running then saw both), after the board's settle time;
- electrical-dark correction and non-linearity correction (``[detector].correct_dark_counts``,
  ``correct_nonlinearity``) are applied when the device offers them: a correction the device refuses is dropped
  with a log line, once;
- a reading of ``n`` repeats is ``n`` scans averaged (mean and sample standard deviation per pixel); a scan
  whose brightest pixel reaches the saturation counts as a saturated repeat;
- a dark turns the source off (:class:`acquisition.devices.board.BoardBacked`): the board's ``SOURCE`` pin, the
  device's shutter, or the operator.

The library is passed in as ``library`` (the module ``seabreeze.spectrometers``, imported when None), so the
test suite can hand the driver a stand-in (:mod:`simulator.devices.seabreeze_standin`, through
``Bench.detector_library``). Counts are the device's (arbitrary units, per scan at the integration time).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from acquisition.calibration import Reading
from acquisition.devices.board import BoardBacked
from acquisition.devices.serial_link import SerialLink
from acquisition.errors import DeviceError

log = logging.getLogger("acquisition.seabreeze")

__all__ = ["SeabreezeDetector", "import_seabreeze", "INSTALL_HINT"]

INSTALL_HINT = "pip install 'gonio-brdf[seabreeze]' (python-seabreeze; on Linux then run seabreeze_os_setup once)"


def import_seabreeze() -> Any:
    """The module ``seabreeze.spectrometers``; a :class:`DeviceError` naming what to install when it is missing."""
    try:
        import seabreeze.spectrometers as sb  # type: ignore[import-not-found]
    except ImportError as e:
        raise DeviceError(f'[detector] type = "seabreeze" needs python-seabreeze, which is not installed ({e}): '
                          f"{INSTALL_HINT}") from None
    return sb


class SeabreezeDetector(BoardBacked):
    """An Ocean Insight spectrometer; see the module docstring. Times in seconds, readings in the device's counts."""

    type = "seabreeze"

    def __init__(self, library: Any, serial_number: str | None, integration_time_s: float,
                 saturation: float | None = None, correct_dark_counts: bool = True, correct_nonlinearity: bool = True,
                 link: SerialLink | None = None, source_off: str = "auto",
                 min_integration_time_s: float | None = None) -> None:
        super().__init__(link, source_off, name="Ocean Insight spectrometer")
        self.sb = library
        self.serial_number = serial_number
        self.integration_time_s = integration_time_s
        self.min_integration_time_s = min_integration_time_s
        self.config_saturation = saturation
        self.saturation = saturation if saturation is not None else float("inf")
        self.want_dark_correction = correct_dark_counts
        self.want_nonlinearity = correct_nonlinearity
        self.correct_dark_counts = False
        self.correct_nonlinearity = False
        self.wavelengths_nm: np.ndarray | None = None
        self.spec: Any = None
        self.model = ""
        self.limits_us = (1, 10**9)
        self._electrical_dark = 0.0
        self._stale = False

    @property
    def channels(self) -> list[str]:
        if self.wavelengths_nm is None:
            return []
        return [f"{w:.6g}nm" for w in self.wavelengths_nm]

    # -- opening ------------------------------------------------------------------------------------------------
    def _open(self) -> Any:
        """The spectrometer (by serial number, else the first found); a one-line :class:`DeviceError` otherwise."""
        err = getattr(self.sb, "SeaBreezeError", Exception)
        try:
            found = list(self.sb.list_devices())
        except Exception as e:  # noqa: BLE001 - the library's backend failing to load is the same problem
            raise DeviceError(f"{self.name}: python-seabreeze cannot list devices ({e}); {INSTALL_HINT}") from None
        which = f"serial number {self.serial_number!r}" if self.serial_number else "any"
        if not found:
            raise DeviceError(f"{self.name}: no spectrometer found by python-seabreeze ({which}): plug it in by USB "
                              "(and on Linux run seabreeze_os_setup once for the udev rules), or check "
                              "[detector].serial_number")
        try:
            return self.sb.Spectrometer.from_serial_number(self.serial_number)
        except err as e:
            have = ", ".join(f"{getattr(d, 'model', '?')} {getattr(d, 'serial_number', '?')}" for d in found)
            raise DeviceError(f"{self.name}: cannot open the spectrometer ({which}): {e}; connected: {have}; "
                              "check [detector].serial_number") from None

    def _probe_corrections(self) -> None:
        """Ask for each correction once: the ones the device refuses are dropped (logged), as the library
        raises ``SeaBreezeError`` for a correction the device cannot do."""
        err = getattr(self.sb, "SeaBreezeError", Exception)
        for attr, want, kw in (("correct_dark_counts", self.want_dark_correction, "correct_dark_counts"),
                               ("correct_nonlinearity", self.want_nonlinearity, "correct_nonlinearity")):
            if not want:
                continue
            try:
                self.spec.intensities(**{kw: True})
                setattr(self, attr, True)
            except err as e:
                log.info("%s %s: %s; read without it", self.model, self.spec.serial_number, e)
        if self.correct_dark_counts:  # the level the correction takes away: a saturated pixel reads that much less
            raw = self.spec.intensities(correct_dark_counts=False, correct_nonlinearity=False)
            cor = self.spec.intensities(correct_dark_counts=True, correct_nonlinearity=False)
            self._electrical_dark = max(float(np.median(raw - cor)), 0.0)

    def connect(self) -> None:
        """Open the device, read its wavelengths, limits and maximum, choose the corrections, set the integration
        time, learn the board's services and put the sample in place."""
        self.spec = spec = self._open()
        self.model = str(spec.model)
        self.serial_number = str(spec.serial_number)
        self.wavelengths_nm = np.asarray(spec.wavelengths(), dtype=float)
        if self.wavelengths_nm.size < 2 or np.any(np.diff(self.wavelengths_nm) <= 0):
            raise DeviceError(f"{self.name} {self.model} {self.serial_number}: its wavelengths are not increasing")
        lo, hi = (int(x) for x in spec.integration_time_micros_limits)
        self.limits_us = (lo, hi)
        t_us = self.integration_time_s * 1e6
        if not lo <= round(t_us) <= hi:
            raise DeviceError(f"{self.name} {self.model}: [detector].integration_time_s = {self.integration_time_s:g}"
                              f" s is outside the device's range {lo * 1e-6:g} to {hi * 1e-6:g} s")
        if self.min_integration_time_s is not None and self.min_integration_time_s * 1e6 < lo:
            log.info("%s %s: [detector].min_integration_time_s = %g s is shorter than the device's %g s; auto-ranging "
                     "stops there", self.model, self.serial_number, self.min_integration_time_s, lo * 1e-6)
        top = float(spec.max_intensity)
        self.saturation = min(top, self.config_saturation) if self.config_saturation else top
        sh = getattr(getattr(spec, "f", None), "shutter", None)
        if sh is not None:
            self.shutter = sh.set_shutter_open
        self.set_integration_time(self.integration_time_s)
        self._probe_corrections()
        self.connect_board()
        log.info("%s %s (serial %s): %d pixels %.1f-%.1f nm, integration %g-%g s, saturation %g, dark-count "
                 "correction %s, non-linearity correction %s", self.name, self.model, self.serial_number,
                 self.wavelengths_nm.size, self.wavelengths_nm[0], self.wavelengths_nm[-1], lo * 1e-6, hi * 1e-6,
                 self.saturation, "on" if self.correct_dark_counts else "off",
                 "on" if self.correct_nonlinearity else "off")
        self.set_sample("TARGET")

    def close(self) -> None:
        if self.spec is not None:
            try:
                self.spec.close()
            except Exception:  # pragma: no cover - closing a vanished device
                pass
            self.spec = None

    # -- settings -----------------------------------------------------------------------------------------------
    def set_integration_time(self, seconds: float) -> float:
        """Set the integration time (s), rounded to a microsecond and clamped to the device's limits; returns the
        time set."""
        lo, hi = self.limits_us
        us = int(min(max(round(seconds * 1e6), lo), hi))
        try:
            self.spec.integration_time_micros(us)
        except Exception as e:  # noqa: BLE001 - the library's error, in one line
            raise DeviceError(f"{self.name} {self.model}: cannot set the integration time to {us} us: {e}") from None
        if abs(us * 1e-6 - self.integration_time_s) > 1e-12:
            self._stale = True
        self.integration_time_s = us * 1e-6
        return self.integration_time_s

    # -- readings -----------------------------------------------------------------------------------------------
    def _scan(self) -> np.ndarray:
        try:
            out = self.spec.intensities(correct_dark_counts=self.correct_dark_counts,
                                        correct_nonlinearity=self.correct_nonlinearity)
        except Exception as e:  # noqa: BLE001 - a vanished device or a USB error, in one line
            raise DeviceError(f"{self.name} {self.model} {self.serial_number}: reading failed ({e}); is it still "
                              "plugged in?") from None
        out = np.asarray(out, dtype=float)
        if out.shape != self.wavelengths_nm.shape:  # type: ignore[union-attr]
            raise DeviceError(f"{self.name} {self.model}: a scan of {out.size} pixels for "
                              f"{self.wavelengths_nm.size} wavelengths")  # type: ignore[union-attr]
        return out

    def _read(self, n: int) -> Reading:
        if self._stale or self.source_switched:  # the first scan after a change of integration time or a switch
            self._scan()                          # of the source began before it: discarded
            self._stale = self.source_switched = False
        scans = np.stack([self._scan() for _ in range(n)])
        clip = self.saturation - self._electrical_dark - 0.5
        sat = int(np.sum(np.max(scans, axis=1) >= clip))
        std = scans.std(axis=0, ddof=1) if n > 1 else np.zeros(scans.shape[1])
        return Reading(scans.mean(axis=0), std, n, sat)

    def read(self, n: int) -> Reading:
        """``n`` scans with the source on, averaged: mean and standard deviation per pixel (counts)."""
        return self._read(n)

    def dark(self, n: int) -> Reading:
        """``n`` scans with the source off (the board's pin, the shutter or the operator)."""
        return self.with_source_off(self._read, n)

    def describe(self) -> dict[str, Any]:
        """Type, model, serial number, channels, integration time (s), saturation (counts) and corrections."""
        return {"type": self.type, "model": self.model, "serial_number": self.serial_number,
                "channels": len(self.channels), "integration_time_s": self.integration_time_s,
                "saturation": self.saturation, "correct_dark_counts": self.correct_dark_counts,
                "correct_nonlinearity": self.correct_nonlinearity, **self.board_description()}
