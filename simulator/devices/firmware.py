"""The detector board's real firmware (``firmware/detector``) on an emulated ATmega328P.

:func:`build_firmware` runs ``make -C firmware/detector`` (avr-gcc), :func:`build_harness` compiles
``avr_harness.c`` against simavr's libraries, and :class:`EmulatedBoard` runs the harness: the firmware's UART is a
pseudo-terminal (:attr:`EmulatedBoard.port`, to be opened with pyserial like a USB serial port) and the harness's
control channel (its stdin/stdout, described at the top of ``avr_harness.c``) sets the voltage on the ADC input,
reports the gain and source pins, and injects faults (reset, a hung board, line noise, a pulled cable).

With ``on_sync``, the emulation stops at the start of every repeat the firmware integrates (its LED pin rises)
and asks ``on_sync(event)`` for the amplifier's output in counts per conversion (:class:`SyncEvent`): the caller
computes it from the bench's physics for the arms' positions, the gain and the source pins at that moment. It may
return a list: the values of this repeat and of the reading's following ones (then set without a stop).

The ADC reads ``floor(1023 * mV / 5000)`` (AVcc reference, 5 V), clipped at 1023; a reading is the sum of its
conversions. :func:`millivolts` turns a mean count per conversion into the input that gives it on average.
"""

from __future__ import annotations

import logging
import os
import shutil
import subprocess
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

log = logging.getLogger("simulator.firmware")

__all__ = ["FIRMWARE_DIR", "HARNESS_SOURCE", "DEBIAN_PACKAGES", "toolchain_problem", "build_firmware",
           "build_harness", "millivolts", "SyncEvent", "EmulatedBoard", "FirmwareError", "PhysicsFeed",
           "use_circuit"]

REPO = Path(__file__).resolve().parents[2]
FIRMWARE_DIR = REPO / "firmware" / "detector"
HARNESS_SOURCE = Path(__file__).with_name("avr_harness.c")
DEBIAN_PACKAGES = "gcc-avr avr-libc simavr libsimavr-dev libsimavrparts1"
SIMAVR_INCLUDE = Path("/usr/include/simavr")
#: ADC full scale (counts) and its reference (mV): the firmware reads against AVcc = 5 V
ADC_FULL = 1023
VREF_MV = 5000.0


class FirmwareError(RuntimeError):
    """The firmware or the harness cannot be built or started; the message says why in one line."""


def toolchain_problem() -> str | None:
    """None when the firmware and the harness can be built here, else a one-line reason naming what is
    missing and the Debian packages that provide it."""
    need = {"make": "make", "gcc": "gcc", "avr-gcc": "gcc-avr", "avr-objcopy": "binutils-avr"}
    missing = [f"{exe} ({pkg})" for exe, pkg in need.items() if shutil.which(exe) is None]
    if not (SIMAVR_INCLUDE / "sim_avr.h").is_file():
        missing.append(f"simavr's headers {SIMAVR_INCLUDE} (libsimavr-dev)")
    if missing:
        return (f"missing {', '.join(missing)}; install the Debian packages: apt-get install {DEBIAN_PACKAGES} "
                "(scripts/system-packages.sh does it when it can)")
    return None


def _run(cmd: list[str], what: str) -> None:
    try:
        r = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    except OSError as e:
        raise FirmwareError(f"cannot build {what}: {e}") from None
    if r.returncode != 0:
        tail = (r.stderr or r.stdout).strip().splitlines()[-5:]
        raise FirmwareError(f"building {what} failed: {' | '.join(tail)} (Debian packages: {DEBIAN_PACKAGES})")


def build_firmware(build_dir: Path | None = None, gains: str | None = None, sample_changer: bool = False,
                   adc: str = "atmega", monitor: bool = False) -> Path:
    """``make -C firmware/detector`` into ``build_dir`` (default ``firmware/detector/build``); returns the ELF.
    ``gains``: the amplifier's gains by multiplexer channel, e.g. ``"1,10,100"`` (the Makefile's default else);
    ``sample_changer``: the board drives a sample changer on D6 (``SAMPLE REF``/``TARGET``); ``adc``: ``"atmega"``
    (its 10-bit ADC) or ``"ads1115"`` (the 16-bit ADS1115 on I2C); ``monitor``: a monitor photodiode on A1."""
    cmd = ["make", "-s", "-C", str(FIRMWARE_DIR), f"SAMPLE_CHANGER={int(sample_changer)}", f"ADC={adc}",
           f"MONITOR={int(monitor)}"]
    if build_dir is not None:
        cmd.append(f"BUILD={Path(build_dir).resolve()}")
    if gains is not None:
        cmd.append(f"GAINS={gains}")
    _run(cmd, "the detector firmware")
    elf = (Path(build_dir).resolve() if build_dir is not None else FIRMWARE_DIR / "build") / "detector.elf"
    if not elf.is_file():
        raise FirmwareError(f"make built no {elf}")
    return elf


def build_harness(build_dir: Path) -> Path:
    """Compile ``avr_harness.c`` against simavr (gcc) into ``build_dir``; returns the executable. Rebuilt only
    when the source is newer."""
    exe = Path(build_dir) / "avr_harness"
    if exe.is_file() and exe.stat().st_mtime >= HARNESS_SOURCE.stat().st_mtime:
        return exe
    Path(build_dir).mkdir(parents=True, exist_ok=True)
    _run(["gcc", "-O2", "-o", str(exe), str(HARNESS_SOURCE), f"-I{SIMAVR_INCLUDE}", "-lsimavr", "-lsimavrparts",
          "-lutil", "-lm"], "the simavr harness")
    return exe


def millivolts(counts_per_conversion: float, dithered: bool = True) -> float:
    """The ADC input (mV) whose conversions read ``counts_per_conversion`` on average: the ADC truncates, so half
    a count is added (with dither the mean of the truncated readings is then the value; without, its rounding)."""
    return (counts_per_conversion + 0.5) * VREF_MV / ADC_FULL


@dataclass(frozen=True)
class SyncEvent:
    """A repeat starts: ``first`` (the first repeat of a reading), ``n`` repeats of ``nconv`` conversions each
    (integration time ``nconv * 125 us``), gain-select pins ``gsel`` (multiplexer channel), ``source`` pin, the
    emulated time ``t`` (s since power-up)."""

    first: bool
    n: int
    nconv: int
    gsel: int
    source: bool
    t: float
    #: the reading is chopped (CHOP ON): the source switches within each repeat, whose value is on minus off
    chop: bool = False

    @property
    def t_int(self) -> float:
        """Integration time of this repeat (s)."""
        return self.nconv * 125e-6


def _fields(words: list[str]) -> dict[str, str]:
    return dict(w.split("=", 1) for w in words if "=" in w)


class EmulatedBoard:
    """One running harness. ``elf``: the firmware; ``harness``: the compiled harness; ``dither_lsb``: rms noise
    added to every conversion (counts); ``on_sync(event) -> counts per conversion`` (see the module docstring)."""

    def __init__(self, elf: Path, harness: Path, dither_lsb: float = 0.0, seed: int = 0,
                 on_sync: Callable[[SyncEvent], float] | None = None, start_timeout_s: float = 10.0) -> None:
        self.on_sync = on_sync
        self.gsel = 0
        self.source = True
        self.reference = False
        self.events: list[str] = []
        #: (t s, gsel, source) of the latest pin changes (the harness's PIN lines), newest last
        self.pin_history: list[tuple[float, int, bool]] = []
        self.closed = False
        self.sync_error: BaseException | None = None
        self._cond = threading.Condition()
        self._wlock = threading.Lock()
        self._time_replies: list[float] = []
        cmd = [str(harness), "--dither", repr(float(dither_lsb)), "--seed", str(int(seed)), str(elf)]
        try:
            self.proc = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                         text=True, bufsize=1)
        except OSError as e:
            raise FirmwareError(f"cannot start the harness {harness}: {e}") from None
        first = self._first_line(start_timeout_s)
        parts = first.split()
        if len(parts) < 2 or parts[0] != "PTY":
            err = self.proc.stderr.read() if self.proc.poll() is not None else ""  # type: ignore[union-attr]
            self.close()
            raise FirmwareError(f"the harness did not start ({first.strip() or err.strip() or 'no output'})")
        self.port = parts[1]
        self._reader = threading.Thread(target=self._read_control, name="avr-harness control", daemon=True)
        self._reader.start()
        if on_sync is not None:
            self.send("SYNC 1")

    def _first_line(self, timeout_s: float) -> str:
        out: list[str] = []
        t = threading.Thread(target=lambda: out.append(self.proc.stdout.readline()), daemon=True)  # type: ignore[union-attr]
        t.start()
        t.join(timeout_s)
        return out[0] if out else ""

    # -- control channel -----------------------------------------------------------------------------------------
    def send(self, line: str) -> None:
        """One control line (see avr_harness.c); ignored once the harness is gone."""
        with self._wlock:
            if self.closed or self.proc.poll() is not None:
                return
            try:
                self.proc.stdin.write(line + "\n")  # type: ignore[union-attr]
                self.proc.stdin.flush()  # type: ignore[union-attr]
            except (BrokenPipeError, ValueError, OSError):
                pass

    def _read_control(self) -> None:
        try:
            self._control_lines()
        except (ValueError, OSError):
            if not self.proc.stdout or not self.proc.stdout.closed:  # a line it could not parse: said, as before
                raise
            # else the harness's stdout was closed under the read (the board reset or stopped): it is gone
        finally:
            with self._cond:
                self.closed = True
                self._cond.notify_all()

    def _control_lines(self) -> None:
        for line in self.proc.stdout:  # type: ignore[union-attr]
            words = line.split()
            if not words:
                continue
            kind, f = words[0], _fields(words[1:])
            if kind == "SYNC":
                self._sync(f)
                continue
            with self._cond:
                if kind == "PIN":
                    self.gsel, self.source = int(f["gsel"]), f["source"] == "1"
                    self.reference = f.get("reference") == "1"
                    self.pin_history = [*self.pin_history[-7:], (float(f.get("t", "nan")), self.gsel, self.source)]
                elif kind == "TIME":
                    self._time_replies.append(float(f["t"]))
                self.events.append(line.strip())
                self._cond.notify_all()

    def _sync(self, f: dict[str, str]) -> None:
        ev = SyncEvent(f["first"] == "1", int(f["n"]), int(f["nconv"]), int(f["gsel"]), f["source"] == "1",
                       float(f["t"]), f.get("chop") == "1")
        try:
            counts = self.on_sync(ev) if self.on_sync is not None else 0.0
        except BaseException as e:  # keep the board running; the caller sees the error
            log.exception("on_sync failed")
            self.sync_error = e
            counts = 0.0
        if isinstance(counts, (int, float)):
            self.set_counts(counts)
        else:  # this repeat's and the following repeats' values: one round trip a reading
            self.send("ADC " + " ".join(f"{min(millivolts(c), 6500.0):.4f}" for c in counts))
        with self._cond:
            self.events.append(f"SYNC {ev}")
            self._cond.notify_all()

    # -- the bench's side --------------------------------------------------------------------------------------------
    def set_adc(self, mv: float) -> None:
        """The amplifier's output voltage on A0 (mV)."""
        self.send(f"ADC {mv:.4f}")

    def set_counts(self, counts_per_conversion: float) -> None:
        """The ADC input that reads ``counts_per_conversion`` on average (beyond full scale: clipped)."""
        self.set_adc(min(millivolts(counts_per_conversion), 6500.0))

    def set_dither(self, lsb: float) -> None:
        self.send(f"DITHER {lsb:.6g}")

    def until(self, t: float) -> None:
        """Let the board's emulated time run on to ``t`` seconds (it idles); bytes from the host wait for it."""
        self.send(f"UNTIL {t:.9f}")

    def wait_for(self, predicate: Callable[[], bool], timeout_s: float = 5.0) -> bool:
        """Wait until ``predicate()`` holds (checked on every control line); False at the timeout."""
        t_end = time.monotonic() + timeout_s
        with self._cond:
            while not predicate():
                left = t_end - time.monotonic()
                if left <= 0 or self.closed:
                    return predicate()
                self._cond.wait(left)
            return True

    def time(self, timeout_s: float = 5.0) -> float:
        """The board's emulated time (s since power-up), from the harness."""
        with self._cond:
            k = len(self._time_replies)
        self.send("TIME?")
        if not self.wait_for(lambda: len(self._time_replies) > k, timeout_s):
            raise FirmwareError("the harness did not answer TIME?")
        return self._time_replies[k]

    # -- faults ----------------------------------------------------------------------------------------------------
    def reset(self) -> None:
        """Press the reset button: the firmware restarts (banner ``BOOT ... reset=external``), its settings lost."""
        self.send("RESET")

    def freeze(self, on: bool = True) -> None:
        """A hung board: it stops executing (and answering) until ``freeze(False)``."""
        self.send(f"FREEZE {int(on)}")

    def noise(self, data: bytes) -> None:
        """Bytes the host receives as if from line noise on the board's TX line."""
        if data:
            self.send("NOISE " + data.hex())

    def unplug(self) -> None:
        """Pull the USB cable: the pty closes; the host's reads and writes fail."""
        self.send("UNPLUG")

    def close(self) -> None:
        """Stop the harness (idempotent)."""
        self.send("QUIT")
        with self._wlock:
            self.closed = True
        try:
            self.proc.stdin.close()  # type: ignore[union-attr]
        except Exception:
            pass
        try:
            self.proc.wait(timeout=5)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        for f in (self.proc.stdout, self.proc.stderr):
            try:
                f.close()  # type: ignore[union-attr]
            except Exception:
                pass

    def __enter__(self) -> EmulatedBoard:
        return self

    def __exit__(self, *exc) -> None:
        self.close()


class PhysicsFeed:
    """The bench behind an emulated board: at each repeat (:class:`SyncEvent`) the amplifier's output from the
    simulator's physics, and one clock for both.

    ``physics`` (:class:`~simulator.world.physics.BenchPhysics`), ``clock`` (fast time), ``arm_angles(t)`` ->
    (theta_i, theta_o) in degrees, ``lock``: the bench's lock (the Dynamixel port moves the arms meanwhile),
    ``gains``: the amplifier's gains by multiplexer channel.

    A reading is computed as gonio-sim's own controller does (:meth:`SerialController._read_common`): at its first
    repeat, all ``n`` repeats at once with the arms at the middle of each repeat, so the noise is drawn in the same
    order and an all-Python capture with the same seed (and ``[simulator].frontend = "netlist"``) reads the same
    counts. The physics reads through the amplifier's circuit (:func:`use_circuit`): repeat k is fed as
    ``counts / nconv`` per conversion, the circuit's output voltage on the ADC input (the firmware's sum reads the
    simulator's count, up to the ADC's quantisation), clipped where the op-amp clips; a repeat a fault saturates
    (``saturate_rate``) is fed beyond full scale.

    All the reading's values go to the board at its first repeat (one round trip a reading, not one a repeat).
    A reading that starts while the amplifier still settles after the board's last gain or source switch reads
    short of the settled value (:meth:`_settling`).

    Room light (``[simulator].ambient``) is in every value (the physics adds it to the signal); its flicker goes to
    the harness as ``FLICKER`` (its amplitude at this gain), which adds it conversion by conversion. A chopped
    reading (``CHOP ON``: the firmware switches the source within each repeat) gets its dark levels too
    (``DARKADC``: the physics with the source off), which the harness puts on A0 while the source pin is low. The
    monitor photodiode (A1, ``MON``) reads ``[simulator].monitor_mv`` times the source's drift.

    Time: the board's clock (emulated cycles) and the simulator's (``clock``) move together: every jump of the
    simulator's fast time lets the board idle on to it (``UNTIL``), and every reading moves the simulator's clock
    on to the board's (its start, then over its repeats), so ``TIME?`` is the bench time of both.
    """

    def __init__(self, physics, clock, arm_angles: Callable[[float], tuple[float, float]], lock,
                 gains: tuple[float, ...] | None) -> None:
        self.physics = physics
        self.clock = clock
        self.arm_angles = arm_angles
        self.lock = lock
        self.gains = tuple(gains) if gains else (float(physics.detector.gain),)
        self.board: EmulatedBoard | None = None
        self._queue: list[tuple[float, bool]] = []
        self._dark: list[tuple[float, bool]] = []
        self._sent: dict[str, tuple[float, float] | float] = {}
        self.readings = 0

    def attach(self, board: EmulatedBoard) -> None:
        """Feed ``board`` (its ``on_sync``) and let it follow the simulator's clock."""
        self.board = board
        board.on_sync = self
        self.clock.on_jump.append(board.until)
        board.until(self.clock.now())
        board.send("SYNC 1")

    def __call__(self, ev: SyncEvent) -> list[float]:
        """Counts per conversion of this repeat and the reading's following ones (a clipped repeat beyond full
        scale); the simulator's clock moves on to the board's, then over the reading."""
        with self.lock:
            self.clock.jump_to(ev.t)
            if ev.first or not self._queue:
                self._start_reading(ev)
            values, self._queue = self._queue, []
            dark, self._dark = self._dark, []
            self.clock.jump_to(ev.t + len(values) * ev.t_int * (2 if ev.chop else 1))
        if dark and self.board is not None:
            mv = (min(millivolts(c), 6500.0) for c in self._per_conv(dark, ev))
            self.board.send("DARKADC " + " ".join(f"{v:.4f}" for v in mv))
        return self._per_conv(values, ev)

    @staticmethod
    def _per_conv(values: list[tuple[float, bool]], ev: SyncEvent) -> list[float]:
        """Counts per conversion of each repeat (a clipped repeat beyond full scale)."""
        return [ADC_FULL + 1.0 if clipped else counts / ev.nconv for counts, clipped in values]

    def _start_reading(self, ev: SyncEvent) -> None:
        import numpy as np

        det = self.physics.detector
        det.gain = self.gains[ev.gsel] if ev.gsel < len(self.gains) else self.gains[-1]
        det.integration_time_s = ev.t_int
        if self.board is not None:
            self.physics.sample = "REF" if self.board.reference else "TARGET"
        t0 = self.clock.now()
        times = t0 + (np.arange(ev.n) + 0.5) * ev.t_int
        angles = np.array([self.arm_angles(float(t)) for t in times])
        # the room light and the source: one term each, in the physics (photocurrent -> counts)
        codes, sat = self.physics.read(angles[:, 0], angles[:, 1], source_on=ev.source or ev.chop, t_s=times)
        codes = self._settling(ev, codes, angles)
        self._queue = [(float(c), bool(s)) for c, s in zip(codes[:, 0], sat, strict=True)]
        self._dark = []
        if ev.chop:  # the halves with the source off
            codes, sat = self.physics.read(angles[:, 0], angles[:, 1], source_on=False, t_s=times)
            self._dark = [(float(c), bool(s)) for c, s in zip(codes[:, 0], sat, strict=True)]
        self._send_room_and_monitor(det.gain, t0)
        self.readings += 1

    def _send_room_and_monitor(self, gain: float, t0: float) -> None:
        """The room light's flicker at this gain (``FLICKER``) and the monitor photodiode's output (``MON``)."""
        ph = self.physics
        amp_counts = gain * ph.ambient_signal(125e-6) * ph.flicker_depth  # per conversion of 125 us
        flicker = (round(amp_counts * VREF_MV / ADC_FULL, 4), ph.flicker_hz)
        monitor = round(float(ph.cfg.sim.monitor_mv * ph.source_scale(t0)), 4)
        if self.board is None:
            return
        if flicker != self._sent.get("flicker"):
            self.board.send(f"FLICKER {flicker[0]:.4f} {flicker[1]:g}")
            self._sent["flicker"] = flicker
        if monitor != self._sent.get("monitor"):
            self.board.send(f"MON {monitor:.4f}")
            self._sent["monitor"] = monitor

    def _settling(self, ev: SyncEvent, codes, angles):
        """The repeats' counts with the amplifier still settling after the board's last gain or source switch
        (its PIN line's time): each repeat short of the settled value by its mean residual
        (:meth:`simulator.world.frontend.FrontEnd.residual`, the table's settling times) times the step from the
        reading before the switch. A board that waits long enough after a switch reads the settled value."""
        import numpy as np

        fe, board = self.physics.frontend, self.board
        hist = [h for h in getattr(board, "pin_history", []) if h[0] <= ev.t + 1e-9]
        if fe is None or len(hist) < 2 or not np.isfinite(hist[-1][0]):
            return codes
        (t_sw, g_new, s_new), (_, g_old, s_old) = hist[-1], hist[-2]
        det = self.physics.detector
        k = self.physics.range_index()
        settle = max(fe.settle_gain_s[k] if g_new != g_old else 0.0, fe.settle_source_s[k] if s_new != s_old else 0.0)
        tau = settle / np.log(1000.0)
        start = ev.t - t_sw
        if settle <= 0.0 or start > 30.0 * tau:
            return codes
        a = start + np.arange(ev.n) * ev.t_int
        mean_residual = tau / ev.t_int * (np.exp(-a / tau) - np.exp(-(a + ev.t_int) / tau))
        new = self.physics.expected_reading(angles[:, 0], angles[:, 1], source_on=ev.source)
        gain = det.gain
        try:
            det.gain = self.gains[g_old] if g_old < len(self.gains) else gain
            old = self.physics.expected_reading(angles[:, 0], angles[:, 1], source_on=s_old)
        finally:
            det.gain = gain
        return codes - mean_residual[:, None] * (new - old)


def board_gains(port: str, timeout_s: float = 5.0) -> tuple[float, ...]:
    """The amplifier's gains the firmware on ``port`` lists (``DETECTOR?``; asked again if a reply is lost)."""
    import serial

    with serial.Serial(port, 115200, timeout=0.05) as ser:
        t_end = time.monotonic() + timeout_s
        while time.monotonic() < t_end:
            ser.reset_input_buffer()
            ser.write(b"\nDETECTOR?\n")
            buf = b""
            t_try = time.monotonic() + 1.0
            while time.monotonic() < t_try:
                buf += ser.read(max(1, ser.in_waiting))
                lines = buf.split(b"\n")
                for i, line in enumerate(lines[:-1]):
                    if line.startswith(b"DETECTOR ") and lines[i + 1] == b"ok":
                        f = _fields(line.decode("ascii", "replace").split()[1:])
                        if "gains" in f:
                            return tuple(float(g) for g in f["gains"].split(","))
    raise FirmwareError(f"the firmware on {port} did not answer DETECTOR? with its gains")


def start_firmware_detector(bench, elf: Path, build_dir: Path | None = None, dither_lsb: float = 0.5,
                            seed: int = 0, frontend_table: Path | None = None) -> tuple[EmulatedBoard, PhysicsFeed]:
    """Run the firmware ``elf`` as the detector of ``bench`` (a :class:`~simulator.bench.VirtualBench` on a
    Dynamixel bench in fast time): build the harness (into ``build_dir``, default :func:`default_build_dir`), start
    the board, check its gains against ``[detector].gains`` and feed it from the bench's physics through the
    amplifier's circuit (``frontend_table``: another circuit's transfer table; default the committed one). Raises
    :class:`FirmwareError` (a one-line reason) or ValueError for a bench it cannot serve."""
    cfg = bench.cfg
    elf = Path(elf)
    if not elf.is_file():
        raise FirmwareError(f"{elf}: no such file (build it with: make -C firmware/detector)")
    if cfg.motion != "dynamixel":
        raise ValueError("the detector board serves only the detector: it needs a Dynamixel bench "
                         '([bench].motion = "dynamixel")')
    if not bench.clock.fast:
        raise ValueError("the emulated board runs in simulated fast time only ([simulator].time_scale = 0)")
    if cfg.detector.kind != "photodiode":
        raise ValueError("the detector board reads a photodiode ([detector].type = \"photodiode\")")
    problem = toolchain_problem()
    if problem:
        raise FirmwareError(problem)
    harness = build_harness(build_dir or default_build_dir())
    board = EmulatedBoard(elf, harness, dither_lsb=dither_lsb, seed=seed)
    try:
        gains = board_gains(board.port)
        want = cfg.detector.gains
        if want and tuple(sorted(gains)) != tuple(sorted(want)):
            raise FirmwareError(f"the firmware's gains {','.join(f'{g:g}' for g in gains)} are not [detector].gains "
                                f"{','.join(f'{g:g}' for g in want)} (build it with make GAINS=...)")
        use_circuit(bench.physics, frontend_table)
        feed = PhysicsFeed(bench.physics, bench.clock, bench.arm_angles, bench.lock, gains)
        feed.attach(board)
    except BaseException:
        board.close()
        raise
    return board, feed


def use_circuit(physics, table: Path | None = None) -> None:
    """Make ``physics`` read through the amplifier's circuit (:mod:`simulator.world.frontend`: the transfer table
    ngspice made from hardware/frontend/frontend.cir) whatever ``[simulator].frontend`` says: the board's ADC input
    is the circuit's output, clipped where the op-amp clips. The physics' own reading limit (``adc_bits``,
    ``[detector].saturation``: the Python controller's ADC) is lifted: the board's 10-bit ADC clips for itself."""
    from simulator.world.frontend import load_frontend

    physics.frontend = load_frontend(str(table) if table else None)
    physics.detector.adc_bits = 62
    physics.detector.saturation = float("inf")


def default_build_dir() -> Path:
    """Where gonio-sim builds the harness: ``$XDG_CACHE_HOME/gonio-brdf/firmware`` (or ~/.cache)."""
    base = Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache")
    return base / "gonio-brdf" / "firmware"
