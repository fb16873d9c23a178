"""A ``dynamixel_sdk.PortHandler`` that opens ``sim://`` URLs in-process (fast tests, no pty, no threads).

The SDK itself is unmodified: only :meth:`setupPort` differs, using ``serial.serial_for_url`` instead of
``serial.Serial``. With a pty path (``/dev/pts/N``) use the plain ``dynamixel_sdk.PortHandler``.
"""

from __future__ import annotations

import serial
from dynamixel_sdk import PortHandler


class SimPortHandler(PortHandler):
    """PortHandler for ``sim://NAME/dynamixel`` URLs (see :mod:`simulator.ports.protocol_sim`)."""

    def setupPort(self, cflag_baud: int) -> bool:  # noqa: N802 - SDK naming
        if self.is_open:
            self.closePort()
        import simulator  # noqa: F401 - registers the sim:// handler

        self.ser = serial.serial_for_url(self.port_name, baudrate=self.baudrate, timeout=0)
        self.is_open = True
        self.ser.reset_input_buffer()
        self.tx_time_per_byte = (1000.0 / self.baudrate) * 10.0
        return True
