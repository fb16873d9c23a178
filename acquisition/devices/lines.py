"""Lines from a serial port, for the drivers that speak text (the detector board, GRBL)."""

from __future__ import annotations

import time
from typing import Any


def next_line(ser: Any, buf: bytearray, deadline: float) -> bytes | None:
    """The next non-blank line: its bytes without the line end (``\\n`` or ``\\r``), taken from ``buf`` and then
    from ``ser`` (a ``serial.Serial``, read in what it has waiting), or None once ``time.monotonic()`` passes
    ``deadline``. Bytes after the line stay in ``buf``; a port error of ``ser.read`` propagates to the caller."""
    while True:
        for j, b in enumerate(buf):
            if b in (10, 13):
                raw = bytes(buf[:j])
                del buf[: j + 1]
                if raw.strip():
                    return raw
                break  # a blank line (the \n of \r\n): look again
        else:
            if time.monotonic() >= deadline:
                return None
            buf += ser.read(max(1, ser.in_waiting))
