"""Exceptions of the acquisition package, by what the operator has to do about them."""

from __future__ import annotations

import serial

try:  # a vanished tty makes termios calls (flush) fail with termios.error, which is not an OSError
    from termios import error as _TermiosError
except ImportError:  # pragma: no cover - not POSIX
    class _TermiosError(Exception):  # type: ignore[no-redef]
        pass

#: What a driver call raises when the port itself fails (a vanished USB adapter or pty): pyserial's errors,
#: OSError and termios.error. The drivers turn these into :class:`CommError`.
PORT_ERRORS = (serial.SerialException, OSError, _TermiosError)


class AcquisitionError(Exception):
    """Base class of acquisition errors."""


class ConfigError(AcquisitionError, ValueError):
    """A bench config, scene file or plan is invalid; the message names the file and the key. Raised before any
    motion."""


class PlanError(AcquisitionError, ValueError):
    """A plan cannot be run as given (points out of reach, an inconsistent resume); raised before any motion."""


class CommError(AcquisitionError):
    """Communication with a device failed after the bounded retries (timeouts, corrupt replies, a vanished port);
    the message names the device and the failure."""


class DeviceError(AcquisitionError):
    """A device refused a command or reported a fault (hardware error, alarm, a goal not reached)."""


class HardwareError(DeviceError):
    """A latched hardware fault (Dynamixel Hardware Error Status, a controller alarm): the capture stops safely."""


class SampleChanged(AcquisitionError):
    """A resumed capture re-measured the last recorded points and the sample on the bench does not read as the one
    in the slice (swapped, moved): the capture stops before measuring anything new."""


class CaptureInterrupted(AcquisitionError):
    """The capture was stopped by Ctrl-C or SIGTERM (``signum`` tells which)."""

    def __init__(self, message: str, signum: int | None = None) -> None:
        super().__init__(message)
        self.signum = signum


class SaturationWarning(UserWarning):
    """A reading returned with saturated (clipped) repeats: its mean is a lower bound, not a measurement
    (:meth:`acquisition.Bench.read` without auto-ranging)."""
