"""A stand-in for python-seabreeze's ``seabreeze.spectrometers``, not the device and not the library: it honours
the calls the library documents (``list_devices()``, ``Spectrometer.from_serial_number(serial)`` /
``from_first_available()``, ``.integration_time_micros(us)``, ``.integration_time_micros_limits``,
``.wavelengths()``, ``.intensities(correct_dark_counts, correct_nonlinearity)``, ``.max_intensity``,
``.serial_number``, ``.model``, ``.f.shutter``, ``.close()``, ``SeaBreezeError``) with python-seabreeze 2.x's
semantics (checked against its source: a correction the device cannot do raises ``SeaBreezeError``; dark-count
correction subtracts the electrical dark pixels' mean; an opened device cannot be opened twice), and feeds them
the simulator's physics: each ``intensities()`` is one scan taken by the simulated world on the bench's ``usb``
port (:mod:`simulator.devices.usb_detectors`) at the arms' angles, with the sample and source the board set.

The simulated device has electrical dark pixels and stores no non-linearity coefficients, like many USB2000+
units, so a driver meets both answers. A test gives the stand-in to the bench in place of the library::

    from simulator.devices import seabreeze_standin
    bench = Bench.from_config(cfg)
    bench.detector_library = seabreeze_standin.library     # a function of the simulator's ports
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from types import SimpleNamespace
from typing import Any

import numpy as np
import serial

__all__ = ["library", "StandInSpectrometer", "StandInSeaBreezeError", "StandInLink"]


class StandInSeaBreezeError(Exception):
    """The stand-in's ``seabreeze.spectrometers.SeaBreezeError``."""


class StandInLink:
    """One line out, one line back, on the simulator's ``usb`` pseudo-terminal (``timeout_s`` per reply)."""

    def __init__(self, port: str, timeout_s: float = 30.0) -> None:
        self.port = port
        self.timeout_s = timeout_s
        self.ser = serial.Serial(port, 115200, timeout=0.05)
        self.lock = threading.Lock()
        self._buf = bytearray()

    def write(self, line: str) -> None:
        with self.lock:
            self.ser.write((line + "\n").encode("ascii"))

    def ask(self, line: str) -> str:
        """Send ``line`` and return the reply line (stripped)."""
        with self.lock:
            self.ser.write((line + "\n").encode("ascii"))
            deadline = time.monotonic() + self.timeout_s
            while True:
                j = self._buf.find(b"\n")
                if j >= 0:
                    out = bytes(self._buf[:j]).decode("ascii", errors="replace").strip()
                    del self._buf[: j + 1]
                    return out
                if time.monotonic() > deadline:
                    raise TimeoutError(f"no reply to {line!r} on {self.port} within {self.timeout_s:g} s")
                self._buf += self.ser.read(max(1, self.ser.in_waiting))

    def close(self) -> None:
        self.ser.close()


def _fields(reply: str, tag: str) -> dict[str, str]:
    if not reply.startswith(tag + " "):
        raise StandInSeaBreezeError(f"unexpected reply {reply!r}")
    return dict(p.split("=", 1) for p in reply.split()[1:] if "=" in p)


class _Device:
    """The stand-in's ``SeaBreezeDevice`` (what ``list_devices()`` returns)."""

    def __init__(self, link: StandInLink) -> None:
        self.link = link
        info = _fields(link.ask("INFO?"), "INFO")
        self.model = info["model"]
        self.serial_number = info["serial"]
        self.is_open = False
        self.info = info


class StandInSpectrometer:
    """Stand-in of ``seabreeze.spectrometers.Spectrometer`` (not the device); :func:`library` binds it to the
    devices of one simulated bench."""

    _devices: Callable[[], list[_Device]] = staticmethod(lambda: [])

    def __init__(self, device: _Device) -> None:
        if not isinstance(device, _Device):
            raise TypeError(f"`device` has to be a `SeaBreezeDevice` instance, got {device!r}")
        self._dev = device
        device.is_open = True
        self._dp = device.info.get("dark_pixels") == "1"
        self._wavelengths = np.array([float(x) for x in device.link.ask("WL?").split(" ", 1)[1].split(",")])
        self.f = SimpleNamespace(shutter=None)  # the feature accessor: this model has no shutter

    @classmethod
    def from_first_available(cls) -> StandInSpectrometer:
        for dev in cls._devices():
            if not dev.is_open:
                return cls(dev)
        raise StandInSeaBreezeError("No unopened device found.")

    @classmethod
    def from_serial_number(cls, serial: str | None = None) -> StandInSpectrometer:
        if serial is None:
            return cls.from_first_available()
        for dev in cls._devices():
            if dev.serial_number == str(serial):
                if dev.is_open:
                    raise StandInSeaBreezeError("Device already opened.")
                return cls(dev)
        raise StandInSeaBreezeError(f"No device attached with serial number '{serial}'.")

    def wavelengths(self) -> np.ndarray:
        return self._wavelengths

    def intensities(self, correct_dark_counts: bool = False, correct_nonlinearity: bool = False) -> np.ndarray:
        if correct_dark_counts and not self._dp:
            raise StandInSeaBreezeError("This device does not support dark count correction.")
        if correct_nonlinearity:  # the simulated device stores no coefficients
            raise StandInSeaBreezeError("This device does not support nonlinearity correction.")
        head, values = self._dev.link.ask("SPECTRUM").rsplit(" ", 1)
        dark = float(_fields(head, "SPECTRUM")["dark"])
        out = np.array([float(x) for x in values.split(",")])
        if correct_dark_counts:  # as python-seabreeze: the electrical dark pixels' mean
            out -= dark
        return out

    @property
    def max_intensity(self) -> float:
        return float(self._dev.info["max"])

    def integration_time_micros(self, integration_time_micros: int) -> None:
        if self._dev.link.ask(f"INT {int(integration_time_micros)}") != "ok":
            raise StandInSeaBreezeError("[Fix] Specified integration time is out of range.")

    @property
    def integration_time_micros_limits(self) -> tuple[int, int]:
        return int(self._dev.info["tmin_us"]), int(self._dev.info["tmax_us"])

    @property
    def serial_number(self) -> str:
        return self._dev.serial_number

    @property
    def model(self) -> str:
        return self._dev.model

    @property
    def pixels(self) -> int:
        return int(self._wavelengths.size)

    def close(self) -> None:
        self._dev.is_open = False


def library(ports: dict[str, str | None]) -> Any:
    """The stand-in of the module ``seabreeze.spectrometers`` for the simulated bench whose ports are ``ports``
    (``gonio-sim serve``'s port line; the spectrometer's world is on ``ports["usb"]``)."""
    port = ports.get("usb")
    if not port:
        raise StandInSeaBreezeError("the simulated bench serves no usb port: is [detector] type = \"seabreeze\"?")
    devices = [_Device(StandInLink(port))]

    def list_devices() -> list[_Device]:
        return list(devices)

    spectrometer = type("Spectrometer", (StandInSpectrometer,), {"_devices": staticmethod(list_devices)})
    return SimpleNamespace(list_devices=list_devices, Spectrometer=spectrometer,
                           SeaBreezeError=StandInSeaBreezeError, __name__="seabreeze.spectrometers (stand-in)")
