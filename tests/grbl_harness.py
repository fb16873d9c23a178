"""GRBL 1.1h's own code on the host, for the conformance tests and ``benchmarks/bench_grbl*.py``: grbl-sim built
by ``make -C firmware/grbl sim`` from ``../shared/grbl`` with the project's configuration (``firmware/grbl/
gonio_config.h``: the homing cycle of the two arms) or GRBL's stock one, and the project's shim
(``firmware/grbl/sim/gonio_shim.c``): the limit switches driven by the simulated arms' steps, and GRBL's main loop
and interrupts on one thread (interrupts as signals, simulated time paced by the main loop's CPU time), so a
loaded machine slows grbl-sim down instead of making it stall or skip (see that file).

The shim reads the serial input itself with read(2) (no stdio buffer, so no ``stdbuf``). A relay between the
driver's pseudo-terminal and grbl-sim's passes the bytes on and is where a test injects bytes the driver did not
send (a reset mid-sweep, as the reset button or a brown-out would; a feed hold from another program). It also
watches the status reports for a frozen move (:class:`StallWatch`), which the shim should make impossible.

Step output: grbl-sim writes ``-s`` through stdio too; to a pseudo-terminal it is line-buffered, so a second pty
takes it and the relay copies it line by line to ``steps.out``; ``-b`` (which grbl-sim flushes itself) goes to
``blocks.out``.
"""

from __future__ import annotations

import os
import pty
import re
import shutil
import subprocess
import threading
import time
import tty
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SHARED_GRBL = REPO.parent / "shared" / "grbl"
GRBL_SRC = SHARED_GRBL / "src" / "grbl"
GRBL_SIM_SRC = SHARED_GRBL / "src" / "grbl-sim"
FIRMWARE = REPO / "firmware" / "grbl"
HOW_TO_GET = ("get GRBL 1.1h's source from its public repository (git clone https://github.com/gnea/grbl, tag "
              "v1.1h, its grbl/ folder) and grbl-sim (https://github.com/grbl/grbl-sim) into "
              "../shared/grbl/src/grbl and ../shared/grbl/src/grbl-sim")


def missing() -> str | None:
    """One plain sentence naming what the conformance tests lack (and how to get it), or None."""
    if not (GRBL_SRC / "grbl.h").is_file() or not (GRBL_SIM_SRC / "simulator.c").is_file():
        return f"GRBL 1.1h's source and grbl-sim are not at {SHARED_GRBL / 'src'}: {HOW_TO_GET}"
    for tool in ("gcc", "make"):
        if shutil.which(tool) is None:
            return f"{tool} is not installed, so grbl-sim (GRBL's host simulator) cannot be built"
    return None


def build(out: Path, config: str = "gonio") -> Path:
    """Build grbl-sim with ``config`` ("gonio": the project's; "stock": GRBL's own) and the shim into ``out``
    (a few seconds); returns the executable."""
    r = subprocess.run(["make", "-s", "-C", str(FIRMWARE), "sim", f"GRBL_SRC={GRBL_SRC}",
                        f"GRBL_SIM_SRC={GRBL_SIM_SRC}", f"BUILD={out}", f"CONFIG={config}"],
                       capture_output=True, text=True, timeout=600)
    if r.returncode != 0:
        raise RuntimeError(f"building grbl-sim ({config}) failed: {r.stdout[-2000:]} {r.stderr[-2000:]}")
    return Path(r.stdout.strip().splitlines()[-1])


STALL_S = 3.0
_MOVING = ("Run", "Jog", "Hold:1")
STATUS_REPORT = re.compile(rb"<(\w+(?::\d)?)\|MPos:([-\d.,]+)")  # (state[:sub], MPos) of a status report


class StallWatch:
    """Status reports in, a stall out: GRBL reporting a moving state (``Run``, ``Jog``, ``Hold:1``) at the same
    ``MPos`` for :data:`STALL_S` s or more, which real GRBL cannot (its stepper interrupt moves the axes every few
    ms). grbl-sim alone did, on a busy machine (its threads' race, ``benchmarks/bench_grbl_stall.py``); with the
    shim it should not: :attr:`stall` is the first one's sentence."""

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
                              f"{now - self._seen_since:.1f} s without a step")
        self._rx = self._rx[cut + 1:]


class GrblSim:
    """grbl-sim running in ``workdir``; :attr:`port` is the path the driver opens. ``report_s``: ``-r``.
    ``switches``: the shim's ``GONIO_GRBL_SWITCHES`` (e.g. "x=-150,y=-200": each arm's start, in steps, below its
    switch; an axis left out has none), ``slip``: ``GONIO_GRBL_SLIP`` (e.g. "y:+200@400")."""

    def __init__(self, exe: Path, workdir: Path, report_s: float = 0.01, switches: str = "",
                 slip: str = "") -> None:
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
        self._test_ser = None
        self._buf = b""
        # the test's end of the port is open before grbl-sim starts: pyserial's open() flushes what is already
        # queued, which could be grbl-sim's first lines on a loaded machine
        self._ser()
        env = {**os.environ, "GONIO_GRBL_SWITCHES": switches, "GONIO_GRBL_SLIP": slip}
        self.proc = subprocess.Popen(
            [str(exe), "-n", "-r", f"{report_s:g}", "-s", os.ttyname(step_slave), "-b", str(self.blocks_path)],
            stdin=self.sim_master, stdout=self.sim_master, stderr=subprocess.DEVNULL, cwd=self.workdir, env=env)
        self._lock = threading.Lock()
        self._stop = threading.Event()
        self.injected: list[bytes] = []
        self.watch = StallWatch()  # the status reports passing to the driver
        self._threads = [threading.Thread(target=f, daemon=True) for f in (self._to_sim, self._from_sim, self._steps)]
        for t in self._threads:
            t.start()

    # -- relay -------------------------------------------------------------------------------------------------------
    def _feed(self, data: bytes) -> None:
        with self._lock:
            os.write(self.sim_slave, data)

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

    def wait_ready(self, timeout_s: float = 30.0) -> list[str]:
        """grbl-sim's start-up output up to its welcome line (its first start prints error:7, no EEPROM yet)."""
        try:
            return self._lines_until(lambda t: t.startswith("Grbl 1.1"), timeout_s, "welcome line")
        except AssertionError as e:
            code = self.proc.poll()
            raise AssertionError(f"{e} (grbl-sim {'running' if code is None else f'exited with {code}'})") from None

    def send_line(self, line: str, timeout_s: float = 60.0) -> list[str]:
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
            # to the end (each looks at _stop every 50 ms): a relay thread still running after its descriptors are
            # closed would read from their numbers reused by the next grbl-sim's ptys and take its output
            t.join(60.0)
        for fd in (self.drv_master, self._drv_slave, self.sim_master, self.sim_slave, self.step_master,
                   self._step_slave):
            try:
                os.close(fd)
            except OSError:
                pass
