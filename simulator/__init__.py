"""gonio-brdf simulator: a virtual in-plane gonioreflectometer (Dynamixel bus, text-protocol controller, physics).

Importing the package registers the pyserial URL handler ``sim://`` (see :mod:`simulator.ports.protocol_sim`).
Start a bench on pseudo-terminals with ``gonio-sim serve --config configs/simulated.toml``.
"""

from __future__ import annotations

import serial as _serial

if "simulator.ports" not in _serial.protocol_handler_packages:
    _serial.protocol_handler_packages.append("simulator.ports")

__version__ = "0.1.0"

__all__ = ["__version__"]
