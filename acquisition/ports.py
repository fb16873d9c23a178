"""The ports a bench file names, by the key that names them: which ``[bench]`` key to fix when a port cannot be
opened (:func:`name_the_key`), and ``gonio-capture --check``'s look at each (:func:`check_ports`: opened and
closed again at once, nothing sent, nothing moved). A simulated bench's ports are the simulator's pseudo-terminals,
made when the capture starts: no key names them.
"""

from __future__ import annotations

from dataclasses import dataclass

from acquisition.config import BenchConfig
from acquisition.devices.driver import Port, port_value
from acquisition.devices.registry import driver_for
from acquisition.devices.serial_link import probe_port
from acquisition.errors import PortError

__all__ = ["PortUse", "configured_ports", "name_the_key", "check_ports", "describe_ports"]


@dataclass(frozen=True)
class PortUse:
    """A port of the bench file: its key (``[bench].serial_port``, ``[motion.grbl].port``, ...), the device on it,
    the port and its baud rate."""

    key: str
    device: str
    port: str
    baudrate: int


def configured_ports(cfg: BenchConfig) -> list[PortUse]:
    """The ports a capture on this bench opens, in the order it opens them (none for a simulated bench): those
    the drivers of its detector and its arms declare (:mod:`acquisition.devices.registry`) that the file gives."""
    b = cfg.bench
    if b.transport == "simulated":
        return []
    drivers = (driver_for("detector", cfg.detector.type, cfg.path), driver_for("motion", b.motion, cfg.path))
    by_name: dict[str, list[Port]] = {}
    for p in (p for d in drivers for p in d.ports):
        by_name.setdefault(p.name, []).append(p)
    uses = []
    for same in by_name.values():  # a bench whose detector is a USB instrument may have no board: no port then
        port = port_value(cfg, same[0].key)
        if port:
            uses.append(PortUse(same[0].key, _together([p.device for p in same]), port,
                                port_value(cfg, same[0].baudrate_key)))
    return uses


def _together(devices: list[str]) -> str:
    """Devices on one port as a message names them: "detector and stepper controller"."""
    devices = list(dict.fromkeys(devices))
    if len(devices) > 1 and all(d.endswith(" controller") for d in devices):
        return " and ".join(d[:-len(" controller")] for d in devices) + " controller"
    return " and ".join(devices)


def name_the_key(e: PortError, cfg: BenchConfig) -> PortError:
    """``e`` (a port that cannot be opened) as one line naming the bench file's key to fix; ``e`` itself when no
    key names the port (a simulated bench's)."""
    use = next((u for u in configured_ports(cfg) if u.port == e.port), None)
    if use is None:
        return e
    msg = (f"{cfg.path}: {use.key} = {use.port!r}: cannot open the {use.device}'s port ({e.reason}); "
           f"set {use.key.split('.')[-1]} to the port it is on (e.g. ls /dev/serial/by-id/)")
    return PortError(msg, e.port, e.reason)


def check_ports(cfg: BenchConfig) -> list[tuple[PortUse, str | None]]:
    """Each port of the bench file and why it cannot be opened (None: it can). Nothing is sent on it."""
    return [(u, probe_port(u.port, u.baudrate)) for u in configured_ports(cfg)]


def describe_ports(cfg: BenchConfig) -> list[str]:
    """``--check``'s lines on the ports: each key, its port and whether it can be opened (nothing is sent)."""
    lines = []
    for use, why in check_ports(cfg):
        state = "can be opened" if why is None else f"warning: cannot be opened ({why})"
        lines.append(f"port {use.key} = {use.port!r} ({use.device}): {state}")
    return lines
