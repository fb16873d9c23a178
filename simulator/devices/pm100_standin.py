"""A stand-in for pyvisa's ``ResourceManager`` and a Thorlabs PM100's message-based resource, not the device and
not pyvisa: it honours the calls the power-meter driver makes of pyvisa (``ResourceManager()``,
``.list_resources()``, ``.open_resource(name)``, ``.close()``; on the resource ``.write(cmd)``, ``.query(cmd)``,
``.read()``, ``.timeout`` (ms), ``.read_termination``, ``.write_termination``, ``.close()``) and carries the SCPI
lines to the simulated meter on the bench's ``usb`` port (:mod:`simulator.devices.usb_detectors`), which answers
from the simulator's physics (power at the arms' angles, with the sample and source the board set).

The SCPI dialogue itself is checked against pyvisa with pyvisa-sim (``tests/data/pm100-sim.yaml``); this
stand-in exists because pyvisa-sim's answers are fixed strings, while a whole capture needs the power the world
gives. A test gives it to the bench in place of pyvisa::

    from simulator.devices import pm100_standin
    bench.detector_library = pm100_standin.library       # a function of the simulator's ports
"""

from __future__ import annotations

from typing import Any

from simulator.devices.seabreeze_standin import StandInLink

__all__ = ["library", "StandInResourceManager", "StandInResource", "RESOURCE", "StandInVisaError"]

#: The VISA resource name of the simulated meter.
RESOURCE = "USB0::0x1313::0x8072::SIM-PM-0001::INSTR"


class StandInVisaError(Exception):
    """The stand-in's ``pyvisa.errors.VisaIOError`` (a timeout: a query the meter did not answer)."""


class StandInResource:
    """Stand-in of ``pyvisa.resources.MessageBasedResource`` on the simulated meter (not the device)."""

    def __init__(self, link: StandInLink, name: str) -> None:
        self.link = link
        self.resource_name = name
        self.timeout = 2000.0  # ms, as pyvisa's
        self.read_termination = "\n"
        self.write_termination = "\n"
        self._pending: str | None = None

    def write(self, message: str) -> int:
        if message.rstrip().endswith("?"):
            self._pending = self.query(message)
        else:
            self.link.write(message)
        return len(message)

    def read(self) -> str:
        if self._pending is None:
            raise StandInVisaError("VI_ERROR_TMO (-1073807339): Timeout expired before operation completed.")
        out, self._pending = self._pending, None
        return out

    def query(self, message: str) -> str:
        self.link.timeout_s = max(self.timeout / 1000.0, 0.1)
        try:
            return self.link.ask(message)
        except TimeoutError:
            raise StandInVisaError("VI_ERROR_TMO (-1073807339): Timeout expired before operation completed."
                                   ) from None

    def close(self) -> None:
        pass


class StandInResourceManager:
    """Stand-in of ``pyvisa.ResourceManager`` with one simulated PM100 on it (not pyvisa)."""

    def __init__(self, port: str) -> None:
        self.link = StandInLink(port)

    def list_resources(self, query: str = "?*::INSTR") -> tuple[str, ...]:
        return (RESOURCE,)

    def open_resource(self, name: str, **kw: Any) -> StandInResource:
        if name != RESOURCE:
            raise StandInVisaError(f"VI_ERROR_RSRC_NFOUND (-1073807343): no resource {name!r}")
        res = StandInResource(self.link, name)
        for k, v in kw.items():
            setattr(res, k, v)
        return res

    def close(self) -> None:
        self.link.close()


def library(ports: dict[str, str | None]) -> Any:
    """The stand-in of ``pyvisa.ResourceManager`` (a callable giving a resource manager) for the simulated bench
    whose ports are ``ports``; the meter's world is on ``ports["usb"]``."""
    port = ports.get("usb")
    if not port:
        raise StandInVisaError("the simulated bench serves no usb port: is [detector] type = \"pm100\"?")
    return lambda *args: StandInResourceManager(port)
