"""GRBL 1.1h's own host simulator (grbl-sim, built from ``../shared/grbl``) on a pseudo-terminal, for the
conformance tests and ``benchmarks/bench_grbl.py``.

grbl-sim reads its stdin with ``select`` + ``getchar``: a buffered stdin takes every byte waiting on the
descriptor into stdio's buffer but hands GRBL one, so the rest of a line written at once waits there until more
bytes arrive (the last line's answer would come one line late). A real UART has no such buffer; grbl-sim is
therefore started under ``stdbuf -i0`` (coreutils: stdin unbuffered, one byte per read), and where ``stdbuf`` is
missing a relay passes the bytes on one at a time, each once grbl-sim has read the one before (``FIONREAD`` on its
side of the pty; fragile on a loaded machine). The relay between the driver's port and grbl-sim is also where a
test injects bytes the driver did not send (a reset mid-sweep, as the reset button or a brown-out would).

Step output: grbl-sim writes ``-s`` through stdio too; to a pseudo-terminal it is line-buffered, so a second pty
takes it and the relay copies it line by line to ``steps.out``; ``-b`` (which grbl-sim flushes itself) goes to
``blocks.out``.
"""

from __future__ import annotations

import fcntl
import os
import pty
import re
import shutil
import struct
import subprocess
import termios
import threading
import time
import tty
from pathlib import Path

SHARED_GRBL = Path(__file__).resolve().parents[1].parent / "shared" / "grbl"


def missing() -> str | None:
    """One plain sentence naming what the conformance tests lack, or None."""
    if not (SHARED_GRBL / "build.sh").is_file():
        return f"the GRBL 1.1h sources and build script are not at {SHARED_GRBL} (../shared/grbl beside the repository)"
    for tool in ("gcc", "make"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed, so grbl-sim (GRBL's host simulator) cannot be built"
    return None


def build(out: Path) -> Path:
    """Build grbl-sim into ``out`` (about 2-6 s); returns the executable."""
    r = subprocess.run(["bash", str(SHARED_GRBL / "build.sh"), str(out)], capture_output=True, text=True, timeout=300)
    if r.returncode != 0:
        raise RuntimeError(f"building grbl-sim failed: {r.stdout[-2000:]} {r.stderr[-2000:]}")
    return Path(r.stdout.strip().splitlines()[-1])


STALL_S = 3.0
STALLS: list[str] = []  # this process's grbl-sim stalls (the conformance tests clear it before each test)
_MOVING = ("Run", "Jog", "Hold:1")
STATUS_REPORT = re.compile(rb"<(\w+(?::\d)?)\|MPos:([-\d.,]+)")  # (state[:sub], MPos) of a status report


def stalled_during_test() -> bool:
    """Whether a grbl-sim of this process stalled since :data:`STALLS` was last cleared (the conformance tests'
    rerun condition: pytest-rerunfailures runs such a test again, on a fresh grbl-sim).

    A stall: GRBL reports a moving state (``Run``, ``Jog``, ``Hold:1``) at the same ``MPos`` for
    :data:`STALL_S` s or more, seen in the status reports the relay passes on. Real GRBL cannot: in those states
    its stepper interrupt moves the axes every few ms. grbl-sim runs GRBL's main loop and the simulated interrupts
    in two unsynchronised threads (``sim_loop`` in ``simulator.c``; ``cli()`` only clears a flag the other thread
    reads once per tick), so on two host cores an interrupt routine runs *beside* the main loop, and when the
    machine is busy the main loop can be descheduled while the interrupt empties the stepper's segment buffer,
    neither of which the single-core AVR allows. Measured by ``benchmarks/bench_grbl_stall.py`` (back-and-forth
    moves, ``$110`` 36000, ``$120`` 4000, polled with ``?`` beside one CPU burner): stalls after 64, 23, 18 and
    27 s at 100 Hz; after 55 s, and none in 180 s, at 20 Hz. A soft reset, ``$X`` and a move on the stalled
    grbl-sim moved again once by hand and stayed in ``Run`` in the benchmark's checks, so a test starts again on a
    fresh grbl-sim. Pinning grbl-sim to one CPU starves its two busy threads instead (the conformance tests then
    time out).
    """
    return bool(STALLS)


def _pending(fd: int) -> int:
    return struct.unpack("i", fcntl.ioctl(fd, termios.FIONREAD, b"\0\0\0\0"))[0]


class StallWatch:
    """Status reports in, a stall out (see :func:`stalled_during_test`): :attr:`stall` is the first one's sentence,
    also appended to :data:`STALLS`."""

    def __init__(self) -> None:
        self.stall: str | None = None
        self._rx = b""
        self._seen: tuple[bytes, bytes] | None = None
        self._seen_since = 0.0

    def feed(self, data: bytes, now: float | None = None) -> None:
        """Bytes from grbl-sim as they arrive (a report may be split across calls); ``now``: their time
        (time.monotonic(), s), for a test of this class."""
        self._rx = (self._rx + data)[-4096:]
        cut = self._rx.rfind(b">")
        if cut < 0:
            return
        now = time.monotonic() if now is None else now
        for m in STATUS_REPORT.finditer(self._rx[:cut + 1]):
            key = (m.group(1), m.group(2))
            if key != self._seen:
                self._seen, self._seen_since = key, now
            elif key[0].decode() in _MOVING and now - self._seen_since >= STALL_S and self.stall is None:
                self.stall = (f"grbl-sim stalled: {key[0].decode()} at MPos {key[1].decode()} for "
                              f"{now - self._seen_since:.1f} s without a step (its threads' race; see "
                              "tests/grbl_harness.stalled_during_test)")
                STALLS.append(self.stall)
        self._rx = self._rx[cut + 1:]


class GrblSim:
    """grbl-sim running in ``workdir``; :attr:`port` is the path the driver opens. ``report_s``: ``-r``."""

    def __init__(self, exe: Path, workdir: Path, report_s: float = 0.01) -> None:
        self.workdir = Path(workdir)
        self.workdir.mkdir(parents=True, exist_ok=True)
        self.steps_path = self.workdir / "steps.out"
        self.blocks_path = self.workdir / "blocks.out"
        self.steps_path.write_bytes(b"")
        # the driver's pty (it opens `port`; the relay holds the master) and grbl-sim's (stdin/stdout = master)
        self.drv_master, drv_slave = pty.openpty()
        tty.setraw(drv_slave)
        tty.setraw(self.drv_master)
        self._drv_slave = drv_slave
        self.port = os.ttyname(drv_slave)
        self.sim_master, self.sim_slave = pty.openpty()
        tty.setraw(self.sim_slave)
        tty.setraw(self.sim_master)
        self.step_master, step_slave = pty.openpty()
        tty.setraw(step_slave)
        self._step_slave = step_slave
        stdbuf = shutil.which("stdbuf")
        self.bytewise = stdbuf is None
        self.proc = subprocess.Popen(
            ([stdbuf, "-i0"] if stdbuf else [])
            + [str(exe), "-n", "-r", f"{report_s:g}", "-s", os.ttyname(step_slave), "-b", str(self.blocks_path)],
            stdin=self.sim_master, stdout=self.sim_master, stderr=subprocess.DEVNULL, cwd=self.workdir)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.injected: list[bytes] = []
        self._test_ser = None
        self._buf = b""
        self.watch = StallWatch()  # the status reports passing to the driver (see stalled_during_test)
        self._threads = [threading.Thread(target=f, daemon=True) for f in (self._to_sim, self._from_sim, self._steps)]
        for t in self._threads:
            t.start()

    # -- relay -------------------------------------------------------------------------------------------------------
    def _feed(self, data: bytes) -> None:
        with self._lock:
            if not self.bytewise:
                os.write(self.sim_slave, data)
                return
            for b in data:
                os.write(self.sim_slave, bytes([b]))
                # the byte reaches grbl-sim's side of the pty a moment later (the tty layer's own buffer): see it
                # arrive (or give it 5 ms), then wait until grbl-sim has read it
                t0 = time.monotonic()
                while not _pending(self.sim_master) and time.monotonic() < t0 + 0.005:
                    time.sleep(0.0001)
                deadline = time.monotonic() + 2.0
                while _pending(self.sim_master) and time.monotonic() < deadline:
                    time.sleep(0.0002)

    def _to_sim(self) -> None:
        import select

        while not self._stop.is_set():
            r, _, _ = select.select([self.drv_master], [], [], 0.05)
            if r:
                try:
                    data = os.read(self.drv_master, 4096)
                except OSError:
                    continue
                self._feed(data)

    def _from_sim(self) -> None:
        import select

        while not self._stop.is_set():
            r, _, _ = select.select([self.sim_slave], [], [], 0.05)
            if r:
                try:
                    data = os.read(self.sim_slave, 4096)
                except OSError:
                    return
                os.write(self.drv_master, data)
                self.watch.feed(data)

    @property
    def stall(self) -> str | None:
        """What the relay saw if grbl-sim stalled, else None."""
        return self.watch.stall

    def _steps(self) -> None:
        import select

        with open(self.steps_path, "ab") as out:
            while not self._stop.is_set():
                r, _, _ = select.select([self.step_master], [], [], 0.05)
                if r:
                    try:
                        data = os.read(self.step_master, 65536)
                    except OSError:
                        return
                    out.write(data.replace(b"\r", b""))
                    out.flush()

    def inject(self, data: bytes) -> None:
        """Bytes to grbl-sim that the driver did not send (e.g. 0x18: the reset button mid-sweep)."""
        self.injected.append(data)
        self._feed(data)

    def _ser(self):
        import serial

        if self._test_ser is None:
            self._test_ser = serial.Serial(self.port, 115200, timeout=0.05)
        return self._test_ser

    def _lines_until(self, done, timeout_s: float, what: str) -> list[str]:
        ser = self._ser()
        out: list[str] = []
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            self._buf += ser.read(4096)
            while b"\n" in self._buf:
                ln, self._buf = self._buf.split(b"\n", 1)
                text = ln.decode(errors="replace").strip()
                if text:
                    out.append(text)
                    if done(text):
                        return out
        raise AssertionError(f"grbl-sim: no {what}: {out}")

    def wait_ready(self, timeout_s: float = 10.0) -> list[str]:
        """grbl-sim's start-up output up to its welcome line (its first start prints error:7, no EEPROM yet)."""
        return self._lines_until(lambda t: t.startswith("Grbl 1.1"), timeout_s, "welcome line")

    def send_line(self, line: str, timeout_s: float = 5.0) -> list[str]:
        """Send one line from the test's side (settings before the driver connects) and return its answer lines;
        :meth:`release` before the driver opens the port."""
        self._ser().write((line + "\n").encode())
        return self._lines_until(lambda t: t == "ok" or t.startswith("error:"), timeout_s, f"answer to {line!r}")

    def release(self) -> None:
        """Close the test's own handle of the port (the driver's turn)."""
        if self._test_ser is not None:
            self._test_ser.close()
            self._test_ser = None

    def close(self) -> None:
        self.release()
        self._stop.set()
        if self.proc.poll() is None:
            self.proc.kill()
        self.proc.wait()
        for t in self._threads:
            t.join(1.0)
        for fd in (self.drv_master, self._drv_slave, self.sim_master, self.sim_slave, self.step_master,
                   self._step_slave):
            try:
                os.close(fd)
            except OSError:
                pass
