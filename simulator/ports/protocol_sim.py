"""pyserial URL handler ``sim://`` for fast in-process use of a virtual bench.

URL forms::

    sim://NAME/serial           the text-protocol controller of the registered bench NAME
    sim://NAME/dynamixel        the Dynamixel bus of that bench (raw Protocol 2.0 bytes)
    sim://NAME/PORT?config=PATH[&seed=N][&time_scale=X]
                                create and register bench NAME from a config file if it does not exist yet

``import simulator`` registers the handler (it appends ``"simulator"`` to ``serial.protocol_handler_packages``);
then ``serial.serial_for_url("sim://bench/serial", timeout=1)`` works. Replies are produced synchronously while
``write`` runs, so nothing depends on thread scheduling. Once the port vanishes (fault injection), ``read``
and ``write`` raise ``serial.SerialException``.
"""

from __future__ import annotations

import threading
import time
import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException, to_bytes

from simulator.ports.transports import get_bench, register_bench


def open_bench_from_url(url: str):
    """Parse a ``sim://`` URL -> (bench, port name); creates and registers the bench if ``config=`` is given."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "sim":
        raise SerialException(f"expected a sim:// URL, got {url!r}")
    name = parts.netloc
    port = parts.path.strip("/") or "serial"
    if port not in ("serial", "dynamixel"):
        raise SerialException(f"{url}: port must be 'serial' or 'dynamixel'")
    opts = {k: v[-1] for k, v in urllib.parse.parse_qs(parts.query).items()}
    bench = get_bench(name)
    if bench is None:
        if "config" not in opts:
            raise SerialException(f"{url}: no bench {name!r} registered and no config= given")
        from simulator.bench import VirtualBench
        from simulator.config import load_config

        over = {}
        if "seed" in opts:
            over["seed"] = int(opts["seed"])
        if "time_scale" in opts:
            over["time_scale"] = float(opts["time_scale"])
        bench = VirtualBench(load_config(opts["config"], **over))
        register_bench(name, bench)
    if port not in bench.ports:
        raise SerialException(f"{url}: this bench has no {port} port")
    return bench, port


class Serial(SerialBase):
    """In-process serial port on a :class:`~simulator.bench.VirtualBench`."""

    def __init__(self, *args, **kwargs) -> None:
        self._rx = bytearray()
        self._cv = threading.Condition()
        self._bench = None
        self._portname = "serial"
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("Port is already open.")
        if self._port is None:
            raise SerialException("Port must be configured before it can be used.")
        self._bench, self._portname = open_bench_from_url(self.portstr)
        self.is_open = True
        self.reset_input_buffer()

    def from_url(self, url: str) -> str:
        return url

    def close(self) -> None:
        self.is_open = False
        with self._cv:
            self._cv.notify_all()

    def _reconfigure_port(self, *args, **kwargs) -> None:
        pass

    def _check(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        if self._portname in self._bench.vanished:
            raise SerialException(f"{self.portstr}: device disconnected")

    @property
    def in_waiting(self) -> int:
        self._check()
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        self._check()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        with self._cv:
            while len(self._rx) < size and self.is_open:
                if deadline is None:
                    self._cv.wait(0.1)
                    self._check()
                    continue
                left = deadline - time.monotonic()
                if left <= 0:
                    break
                self._cv.wait(left)
            data = bytes(self._rx[:size])
            del self._rx[:size]
        return data

    def write(self, data) -> int:
        self._check()
        data = to_bytes(data)
        reply = self._bench.process(self._portname, data)
        if reply:
            with self._cv:
                self._rx += reply
                self._cv.notify_all()
        return len(data)

    def reset_input_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()
        with self._cv:
            self._rx.clear()

    def reset_output_buffer(self) -> None:
        if not self.is_open:
            raise PortNotOpenError()

    @property
    def out_waiting(self) -> int:
        return 0

    def _update_break_state(self) -> None:
        pass

    def _update_rts_state(self) -> None:
        pass

    def _update_dtr_state(self) -> None:
        pass

    @property
    def cts(self) -> bool:
        return True

    @property
    def dsr(self) -> bool:
        return True

    @property
    def ri(self) -> bool:
        return False

    @property
    def cd(self) -> bool:
        return True
