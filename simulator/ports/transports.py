"""Transports: pseudo-terminal pairs for the real SDK / pyserial, and a registry of in-process benches.

:class:`PtyPort` opens a pty pair, puts the slave in raw mode and keeps it open (so the master never sees a
hang-up when a client closes and reopens the path), and pumps bytes between the master and the bench in a
thread with ``select``. Clients open :attr:`PtyPort.path` (``/dev/pts/N``) with ``serial.Serial`` or
``dynamixel_sdk.PortHandler``, unmodified.
"""

from __future__ import annotations

import errno
import logging
import os
import select
import threading
import time
import tty

from simulator.bench import VirtualBench

log = logging.getLogger("simulator.transport")

_REGISTRY: dict[str, VirtualBench] = {}
_REG_LOCK = threading.Lock()


def register_bench(name: str, bench: VirtualBench) -> None:
    """Make ``bench`` reachable in-process as ``sim://NAME/dynamixel`` and ``sim://NAME/serial``."""
    with _REG_LOCK:
        _REGISTRY[name] = bench


def unregister_bench(name: str) -> None:
    with _REG_LOCK:
        _REGISTRY.pop(name, None)


def get_bench(name: str) -> VirtualBench | None:
    with _REG_LOCK:
        return _REGISTRY.get(name)


class PtyPort:
    """One virtual serial port on a pseudo-terminal, served by a pump thread.

    ``name`` is the bench port ("dynamixel" or "serial"). Call :meth:`start`, open :attr:`path`, and
    :meth:`close` when done (idempotent). When the bench marks the port vanished, both pty fds are closed: the
    client's next read/write fails like an unplugged USB adapter.
    """

    POLL_S = 0.05

    def __init__(self, bench: VirtualBench, name: str) -> None:
        self.bench = bench
        self.name = name
        self.master, self.slave = os.openpty()
        tty.setraw(self.slave)
        tty.setraw(self.master)
        self.path = os.ttyname(self.slave)
        os.set_blocking(self.master, False)
        self._wake_r, self._wake_w = os.pipe()
        self._stop = threading.Event()
        self._closed = False
        self._fd_lock = threading.Lock()
        self._thread = threading.Thread(target=self._run, name=f"pty-{name}", daemon=True)

    def start(self) -> PtyPort:
        self._thread.start()
        return self

    def _write_all(self, data: bytes) -> None:
        view = memoryview(data)
        deadline = time.monotonic() + 1.0
        while view:
            try:
                n = os.write(self.master, view)
                view = view[n:]
            except BlockingIOError:
                if time.monotonic() > deadline:
                    log.warning("%s: client not reading, %d reply bytes dropped", self.name, len(view))
                    return
                select.select([], [self.master], [], 0.05)

    def _run(self) -> None:
        try:
            while not self._stop.is_set():
                r, _, _ = select.select([self.master, self._wake_r], [], [], self.POLL_S)
                if self._stop.is_set():
                    break
                if self.master in r:
                    try:
                        data = os.read(self.master, 4096)
                    except BlockingIOError:
                        continue
                    except OSError as e:
                        if e.errno == errno.EIO:
                            continue  # no client on the slave side right now
                        raise
                    if data:
                        reply = self.bench.process(self.name, data)
                        if reply:
                            self._write_all(reply)
                else:
                    with self.bench.lock:
                        self.bench.check_vanish()
                if self.name in self.bench.vanished:
                    log.warning("%s: port %s vanished", self.name, self.path)
                    self._close_fds()
                    return
        except Exception:
            log.exception("%s: pump thread failed", self.name)
            self._close_fds()
        finally:
            if self._stop.is_set():
                self._close_fds()  # close() left them to this thread (see there)

    def _close_fds(self) -> None:
        with self._fd_lock:
            if self._closed:
                return
            self._closed = True
            for fd in (self.master, self.slave, self._wake_r, self._wake_w):
                try:
                    os.close(fd)
                except OSError:
                    pass

    def close(self) -> None:
        """Stop the pump thread and close all fds."""
        self._stop.set()
        with self._fd_lock:
            if not self._closed:
                try:
                    os.write(self._wake_w, b"x")
                except OSError:
                    pass
        if self._thread.is_alive() and threading.current_thread() is not self._thread:
            self._thread.join(timeout=2.0)
        # a pump thread still running (starved on a loaded machine) closes the fds itself when it stops: closed
        # here under it, their numbers could be reused by the next pty, which the late thread would then serve
        if not self._thread.is_alive():
            self._close_fds()


class PtyServer:
    """All pty ports of one bench: ``{"dynamixel": path or None, "serial": path}``. ``names``: serve only these
    (``gonio-sim serve --detector-firmware`` leaves the serial port to the emulated board)."""

    def __init__(self, bench: VirtualBench, names: tuple[str, ...] | None = None) -> None:
        self.bench = bench
        self.ports: dict[str, PtyPort] = {}
        try:
            for name in bench.ports:
                if names is not None and name not in names:
                    continue
                self.ports[name] = PtyPort(bench, name).start()
        except Exception:
            self.close()
            raise

    def paths(self) -> dict[str, str | None]:
        names = ("dynamixel", "serial", "usb") if "usb" in self.ports else ("dynamixel", "serial")
        out = {name: (self.ports[name].path if name in self.ports else None) for name in names}
        if "grbl" in self.ports:  # a GRBL bench: the arms' controller on a port of its own
            out["grbl"] = self.ports["grbl"].path
        return out

    def close(self) -> None:
        for p in self.ports.values():
            p.close()

    def __enter__(self) -> PtyServer:
        return self

    def __exit__(self, *exc) -> None:
        self.close()
