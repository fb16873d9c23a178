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


class PortError(CommError):
    """A port cannot be opened (it does not exist, is busy, or may not be opened by this user): raised when a bench
    opens, before anything moves. ``port`` names it, ``reason`` says why in a few words (:func:`port_reason`)."""

    def __init__(self, message: str, port: str, reason: str) -> None:
        super().__init__(message)
        self.port = port
        self.reason = reason


def port_reason(e: BaseException) -> str:
    """Why opening a port failed, in a few words: the OS's reason (pyserial's message repeats the port twice)."""
    import errno
    import os

    code = getattr(e, "errno", None)
    if not isinstance(code, int):
        text = str(e).strip()
        return text or type(e).__name__
    hints = {errno.ENOENT: "; is the adapter plugged in, and is this its name?",
             errno.EACCES: "; the user needs access to it (Linux: the dialout group)",
             errno.EBUSY: "; another program has it open"}
    return f"{os.strerror(code).lower()}{hints.get(code, '')}"


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
