"""gonio-brdf simulator: a virtual in-plane gonioreflectometer (Dynamixel bus, text-protocol controller, physics).

Importing the package registers the pyserial URL handler ``sim://`` (see :mod:`simulator.ports.protocol_sim`).
Start a bench on pseudo-terminals with ``gonio-sim serve --config configs/simulated.toml``.
"""

from __future__ import annotations

import serial as _serial

from reconstruction.moved import keep_old_names

if "simulator.ports" not in _serial.protocol_handler_packages:
    _serial.protocol_handler_packages.append("simulator.ports")

#: The module names of the flat layout before the rooms, kept for scripts (``simulator.physics``, ...).
keep_old_names({
    "simulator.dxl_codec": "simulator.devices.dxl_codec",
    "simulator.dxl_servo": "simulator.devices.dxl_servo",
    "simulator.dxl_device": "simulator.devices.dxl_device",
    "simulator.serial_controller": "simulator.devices.serial_controller",
    "simulator.physics": "simulator.world.physics",
    "simulator.motion": "simulator.world.motion",
    "simulator.clock": "simulator.world.clock",
    "simulator.faults": "simulator.world.faults",
    "simulator.transports": "simulator.ports.transports",
    "simulator.protocol_sim": "simulator.ports.protocol_sim",
    "simulator.sdk_port": "simulator.ports.sdk_port",
})

__version__ = "0.1.0"

__all__ = ["__version__"]
