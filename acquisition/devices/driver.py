"""What a driver declares to the bench: the bench file's ``type`` it answers to (``[motion].type`` /
``[bench].motion`` for the arms, ``[detector].type`` for the detector), its section (the schema struct it is
configured by), the ports it opens (by name, and the bench file's key that names each on hardware) and how it
opens and closes. :mod:`acquisition.devices.registry` lists the drivers; :class:`acquisition.bench.Bench` opens
the two a bench file names, and :mod:`acquisition.ports` checks the ports they declare.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from typing import Any, Literal

__all__ = ["Port", "Opening", "Driver", "close_device", "port_value"]


@dataclass(frozen=True)
class Port:
    """A port a driver opens: its ``name`` (``"serial"``, ``"dynamixel"``, ``"grbl"``: a simulated bench's
    pseudo-terminals have the same names), the bench-file ``key`` naming it on hardware (``"[bench].serial_port"``)
    and the key of its baud rate, what is on it (``device``, for messages), and whether the driver needs it
    (``required``; else it uses the port when the file gives one, as a USB detector uses the detector board)."""

    name: str
    key: str
    baudrate_key: str
    device: str
    required: bool = True


@dataclass(frozen=True)
class Opening:
    """What a driver opens with: the bench file (``cfg``), the ports by name (path, ``""`` when not given), the
    detector board's serial link (:class:`acquisition.devices.serial_link.SerialLink`; None when no driver of the
    bench uses it), whether the bench is the simulator, and an external detector's library (or the stand-in a test
    passes). ``cfg`` is an :class:`acquisition.config.BenchConfig` (not imported: the drivers import this module)."""

    cfg: Any
    ports: Mapping[str, str]
    link: Any = None
    simulated: bool = False
    library: Any = None


def close_device(device: Any) -> None:
    """The default way a driver closes: the device's own ``close()``, when it has one."""
    close = getattr(device, "close", None)
    if close is not None:
        close()


@dataclass(frozen=True)
class Driver:
    """One driver: ``role`` ``"motion"`` (the arms: ``move``, ``positions``, ``stop``, ``healthy``, ``release``)
    or ``"detector"`` (:class:`acquisition.devices.protocols.Detector`), answering to the bench file's ``type``;
    ``section`` is the struct of its table (:mod:`reconstruction.schema.bench`); ``open`` builds the device
    from an :class:`Opening` (:class:`~acquisition.bench.Bench` then connects it) and ``close`` closes what it
    opened (a device on the shared serial link leaves the link to the bench). ``library``: an external
    detector's library, imported (and checked) before any port is opened: ``library(cfg, simulated)``."""

    type: str
    role: Literal["motion", "detector"]
    section: type
    ports: tuple[Port, ...]
    open: Callable[[Opening], Any]
    close: Callable[[Any], None] = close_device
    library: Callable[[Any, bool], Any] | None = None


def port_value(cfg: Any, key: str) -> Any:
    """The value of the bench-file ``key`` (``"[bench].serial_port"``, ``"[motion.grbl].port"``) in ``cfg``, or
    None when its table is left out."""
    section, name = key[1:].split("].")
    node = cfg
    for part in section.split("."):
        node = getattr(node, part, None)
        if node is None:
            return None
    return getattr(node, name)
