"""The bench: motion (Dynamixel or stepper arms) plus the detector, opened from a validated config through the
drivers its types name (:mod:`acquisition.devices.registry`).

``transport = "simulated"`` starts ``gonio-sim serve --config FILE`` as a child process (its own session, so a
Ctrl-C in the terminal reaches only the capture, which then parks the arms through the still-running simulator;
``--exit-with-parent`` so a killed capture leaves no orphan) and opens the pseudo-terminals it prints, exactly
as hardware ports. A simulator that refuses its config (exit status 2) raises :class:`ConfigError` with its
message; :func:`check_simulator_config` runs ``gonio-sim check`` to validate the simulator's sections without
starting anything. Nothing here imports the simulator.

Python API for lab-bench scripts::

    from acquisition import Bench

    with Bench.from_config("configs/simulated.toml") as bench:
        plan = bench.plan()                       # the config's [plan]
        print(bench.check(plan).describe())
        result = bench.capture(plan, out="out/run1")
"""

from __future__ import annotations

import json
import logging
import os
import select
import shutil
import signal
import subprocess
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import IO, Any

from acquisition.calibration import Reading
from acquisition.config import BenchConfig, load_config
from acquisition.devices.autorange import AutoRanger
from acquisition.devices.driver import Driver, Opening, port_value
from acquisition.devices.protocols import Devices, MoveStatus
from acquisition.devices.registry import driver_for
from acquisition.devices.serial_link import SerialLink
from acquisition.errors import CommError, ConfigError, DeviceError, PortError, SaturationWarning
from acquisition.plans.geometry import Geometry, Point, Reason
from acquisition.plans.plan import Plan, PlanCheck, load_scene
from acquisition.ports import name_the_key

log = logging.getLogger("acquisition.bench")

__all__ = ["Bench", "SimulatorProcess", "SimulatorCheck", "check_simulator_config"]

#: The simulator's exit status for a config it refuses (``gonio-sim serve`` / ``gonio-sim check``).
SIMULATOR_CONFIG_STATUS = 2


def _simulator_argv(command: str, source: str | Path = "config") -> list[str]:
    """The argv prefix that runs the simulator ``command`` (``gonio-sim``: the console script next to this
    Python, or ``python -m simulator.cli``, a child process: acquisition does not import it). A command that
    cannot be found is a :class:`ConfigError` naming ``[bench].simulator_command`` of ``source``."""
    exe = None
    if command and "\0" not in command and len(command) < 4096:
        exe = shutil.which(command, path=str(Path(sys.executable).parent)) or shutil.which(command)
    if exe is not None:
        return [exe]
    if command == "gonio-sim":
        return [sys.executable, "-m", "simulator.cli"]
    shown = command if len(command) <= 60 else command[:40] + f"... ({len(command)} characters)"
    raise ConfigError(f"{source}: [bench].simulator_command: cannot find the simulator command {shown!r} (not "
                      "next to this Python nor on PATH)")


def _refusal(stderr: str, status: int) -> str:
    """The message of a simulator that exited with ``status``: its last stderr line without the program prefix."""
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    if not lines:
        return f"the simulator exited with status {status} and printed nothing"
    last = lines[-1]
    return last[len("gonio-sim: "):] if last.startswith("gonio-sim: ") else last


def check_simulator_config(config_path: str | Path, command: str = "gonio-sim", timeout_s: float = 60.0) -> None:
    """Validate the simulator's sections of ``config_path`` as ``gonio-sim serve`` would, by running
    ``COMMAND check --config FILE`` (no port is opened). Raises :class:`ConfigError` with the simulator's message
    if it refuses the file, :class:`CommError` if the check cannot be run."""
    SimulatorCheck(config_path, command).result(timeout_s)


class SimulatorCheck:
    """``gonio-sim check --config FILE`` started in the background (so that ``gonio-capture --check`` validates
    the plan meanwhile); :meth:`result` waits for it and raises as :func:`check_simulator_config`."""

    def __init__(self, config_path: str | Path, command: str = "gonio-sim") -> None:
        self.argv = [*_simulator_argv(command, config_path), "check", "--config", str(config_path)]
        try:
            self.proc: subprocess.Popen[bytes] | None = subprocess.Popen(
                self.argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
        except OSError as e:
            raise CommError(f"simulated bench: cannot run {' '.join(self.argv)}: {e}") from None

    def result(self, timeout_s: float = 60.0) -> None:
        assert self.proc is not None
        try:
            _, err_b = self.proc.communicate(timeout=timeout_s)
        except subprocess.TimeoutExpired:
            self.cancel()
            raise CommError(f"simulated bench: {' '.join(self.argv)} gave no answer within {timeout_s:g} s") from None
        err = err_b.decode(errors="replace")
        code = self.proc.returncode
        if code == SIMULATOR_CONFIG_STATUS:
            raise ConfigError(_refusal(err, code))
        if code != 0:
            raise CommError(f"simulated bench: {' '.join(self.argv)} exited with status {code}: "
                            f"{err.strip()[-2000:]}")

    def cancel(self) -> None:
        """Stop the check (the config was refused before its answer was needed)."""
        if self.proc is not None and self.proc.poll() is None:
            self.proc.kill()
            self.proc.communicate()


class SimulatorProcess:
    """``gonio-sim serve`` as a child process; :attr:`ports` is the JSON line it printed. Its stderr goes to
    ``log_path`` (appended; a temporary file without one)."""

    def __init__(self, config_path: str | Path, command: str = "gonio-sim", log_path: str | Path | None = None,
                 extra_args: tuple[str, ...] = (), timeout_s: float = 30.0) -> None:
        self.config_path = Path(config_path)
        self.command = command
        self.log_path = Path(log_path) if log_path is not None else None
        self.extra_args = extra_args
        self.timeout_s = timeout_s
        self.proc: subprocess.Popen[bytes] | None = None
        self.ports: dict[str, str | None] = {}
        self.stdout_rest = b""  # what the child printed after its port line (nothing, by its protocol)
        self._log_fh: IO[bytes] | None = None
        self._log_start = 0  # where this child's output begins in the log file (earlier runs' logs precede it)

    def _argv(self) -> list[str]:
        return [*_simulator_argv(self.command, self.config_path), "serve", "--config", str(self.config_path),
                "--exit-with-parent",
                "--log-level", "info", *self.extra_args]

    def start(self) -> dict[str, str | None]:
        """Start the child and wait for its port line. Raises :class:`ConfigError` with the simulator's message
        if it refuses the config (exit status 2), else :class:`CommError` with its stderr if it fails."""
        argv = self._argv()
        if self.log_path is not None:
            self._log_fh = open(self.log_path, "a+b")  # appended to, and read back for the error message
            self._log_fh.seek(0, os.SEEK_END)
        else:
            self._log_fh = tempfile.TemporaryFile()
        self._log_start = self._log_fh.tell()
        err: Any = self._log_fh
        log.info("starting the simulator: %s", " ".join(argv))
        self.proc = subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=err, stdin=subprocess.DEVNULL,
                                     start_new_session=True)
        assert self.proc.stdout is not None
        deadline = time.monotonic() + self.timeout_s
        line = b""
        fd = self.proc.stdout.fileno()
        while not line.endswith(b"\n"):
            left = deadline - time.monotonic()
            r, _, _ = select.select([fd], [], [], max(left, 0.0))
            if not r:
                self.stop()
                raise CommError(f"simulated bench: {' '.join(argv)} printed no port line within "
                                f"{self.timeout_s:g} s")
            ch = os.read(fd, 1)
            if not ch:
                status = self.proc.wait()
                tail = self._stderr_tail()
                if status == SIMULATOR_CONFIG_STATUS:
                    raise ConfigError(_refusal(tail, status))
                raise CommError(f"simulated bench: the simulator exited with status {status}: "
                                f"{tail or '(nothing on stderr)'}")
            line += ch
        try:
            self.ports = json.loads(line)
        except json.JSONDecodeError:
            self.stop()
            raise CommError(f"simulated bench: unexpected first line from the simulator: {line!r}") from None
        log.info("simulator ports: %s", self.ports)
        return self.ports

    def _stderr_tail(self) -> str:
        """The last 2000 bytes the child wrote to its log (only this child's, not an earlier run's)."""
        if self._log_fh is None:
            return ""
        try:
            self._log_fh.flush()
            self._log_fh.seek(0, os.SEEK_END)
            size = self._log_fh.tell()
            self._log_fh.seek(max(self._log_start, size - 2000))
            return self._log_fh.read().decode(errors="replace").strip()
        except OSError:  # pragma: no cover
            return ""

    def stop(self, timeout_s: float = 5.0, sig: int = signal.SIGTERM) -> int | None:
        """Send ``sig`` (SIGTERM; ``gonio-sim serve`` exits 0 on SIGTERM and SIGINT) and wait (SIGKILL after
        ``timeout_s``); returns its exit status."""
        if self.proc is None:
            return None
        if self.proc.poll() is None:
            try:
                self.proc.send_signal(sig)
                self.proc.wait(timeout_s)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout is not None and not self.proc.stdout.closed:
            self.stdout_rest = self.proc.stdout.read()  # the child is gone: reads up to EOF
            if self.stdout_rest:
                log.warning("the simulator printed more than its port line: %r", self.stdout_rest[:200])
            self.proc.stdout.close()
        if self._log_fh is not None:
            self._log_fh.close()
            self._log_fh = None
        return self.proc.returncode


#: How a message names a simulated bench's port.
_PORT_NAMES = {"dynamixel": "Dynamixel", "grbl": "GRBL"}


class Bench:
    """A gonioreflectometer: ``motion`` (arms) and ``detector``, opened from a :class:`BenchConfig`.

    Use as a context manager (or :meth:`open` / :meth:`close`). Angles in degrees.
    """

    def __init__(self, cfg: BenchConfig, simulator_log: str | Path | None = None) -> None:
        self.cfg = cfg
        self.geometry = Geometry.from_config(cfg)
        self.simulator_log = simulator_log
        self.sim: SimulatorProcess | None = None
        self.link: SerialLink | None = None
        self.detector: Any = None  # SerialDetector, or an external one (acquisition.devices.external)
        #: test hook (docs/detectors.md): a function of the simulator's ports returning the stand-in of the
        #: detector's library (seabreeze.spectrometers, pyvisa.ResourceManager); None: the real library
        self.detector_library: Any = None
        self.motion: Any = None  # the arms, from the driver of [bench].motion (acquisition.devices.registry)
        #: the drivers that opened the arms and the detector (motion, detector)
        self.drivers: tuple[Driver, Driver] | None = None
        #: extra arguments of ``gonio-sim serve`` (the engine passes ``--attempt N`` on a resumed capture)
        self.sim_args: tuple[str, ...] = ()
        self._opened = False
        self._wall0 = time.monotonic()
        self._ranger: AutoRanger | None = None  # read()'s auto-ranging, once used
        self._ref_dark: Reading | None = None  # the last dark() (at the reference setting)
        self._resume_flags = ""

    @classmethod
    def from_config(cls, path: str | Path, **kw: Any) -> Bench:
        """Load and validate the bench file at ``path`` (nothing is opened or moved yet)."""
        return cls(load_config(path), **kw)

    # -- plans ---------------------------------------------------------------------------------------------------
    def plan(self, scene: str | Path | None = None) -> Plan:
        """The config's ``[plan]``, optionally restricted to a scene file."""
        p = Plan.from_config(self.cfg.plan, self.cfg.base_dir)
        if scene is not None:
            p = p.restrict(load_scene(scene))
        return p

    def check(self, plan: Plan) -> PlanCheck:
        """Measurable and unmeasurable points of ``plan`` on this bench (no motion)."""
        return plan.check(self.geometry)

    # -- life cycle --------------------------------------------------------------------------------------------
    @property
    def is_open(self) -> bool:
        return self._opened

    def open(self) -> Bench:
        """Connect (starting the simulator for a simulated bench) and initialise every device: the arms and the
        detector through the drivers of their types (:mod:`acquisition.devices.registry`)."""
        if self._opened:
            return self
        cfg = self.cfg
        b = cfg.bench
        try:
            motion_drv = driver_for("motion", b.motion, cfg.path)
            det_drv = driver_for("detector", cfg.detector.type, cfg.path)
            self.drivers = (motion_drv, det_drv)
            ports = self._ports(motion_drv, det_drv)
            lib = None
            if det_drv.library is not None:  # an external detector's library first, before any port is opened
                lib = self.detector_library(self.sim.ports if self.sim else {}) if self.detector_library else \
                    det_drv.library(cfg, self.sim is not None)
            on_link = [p for d in self.drivers for p in d.ports if p.name == "serial"]
            if any(p.required for p in on_link) or (on_link and ports.get("serial")):
                self.link = SerialLink(ports.get("serial") or "", b.serial_baudrate, b.serial_timeout_s,
                                       cfg.motion.retries)
            opening = Opening(cfg, ports, self.link, self.sim is not None, lib)
            self.detector = det_drv.open(opening)
            if sys.stdin is not None and sys.stdin.isatty():
                self.detector.manual_swap = _prompt_swap
            self.detector.connect()
            self.motion = motion_drv.open(opening)
            self.motion.connect()
            self._opened = True
            self._wall0 = time.monotonic()
            log.info("bench %r open: transport %s, motion %s, detector %s (%d channel(s))", b.name, b.transport,
                     b.motion, self.detector.type, len(self.detector.channels))
        except PortError as e:  # a port that cannot be opened: which key of the bench file names it
            self.close()
            raise name_the_key(e, cfg) from None
        except BaseException:
            self.close()
            raise
        return self

    def _ports(self, *drivers: Driver) -> dict[str, str]:
        """The ports by name: a simulated bench's pseudo-terminals (the simulator started now), else the bench
        file's keys that the drivers declare. A port a driver needs that the simulator does not offer is a
        :class:`CommError`."""
        cfg = self.cfg
        if cfg.bench.transport != "simulated":
            return {p.name: port_value(cfg, p.key) or "" for d in drivers for p in d.ports}
        self.sim = SimulatorProcess(cfg.path, cfg.bench.simulator_command, self.simulator_log,
                                    extra_args=self.sim_args)
        ports = {k: v or "" for k, v in self.sim.start().items()}
        for p in (p for d in drivers for p in d.ports if p.required and p.name != "serial"):
            if not ports.get(p.name):
                raise CommError(f"simulated bench: the simulator offers no {_PORT_NAMES.get(p.name, p.name)} port "
                                "(is [bench].motion consistent?)")
        return ports

    def close(self) -> None:
        """Close ports and stop the simulator (does not move anything: see :meth:`shutdown`): each device through
        the driver that opened it, then the serial link they share."""
        motion_drv, det_drv = self.drivers if self.drivers is not None else (None, None)
        if self.motion is not None and motion_drv is not None:
            motion_drv.close(self.motion)
        if self.detector is not None and det_drv is not None:
            det_drv.close(self.detector)
        if self.link is not None:
            self.link.close()
        if self.sim is not None:
            self.sim.stop()
        self._resume_flags = self.resume_flags()  # the driver's word outlives it
        self.sim = None
        self.link = None
        self.detector = None
        self.motion = None
        self._ranger = self._ref_dark = None
        self._opened = False

    def resume_flags(self) -> str:
        """What ``gonio-capture --resume`` needs added after this run, in the arms' driver's word (GRBL in alarm
        on a bench without switches: ``" --unlock"``; nothing otherwise)."""
        flags = getattr(self.motion, "resume_flags", None) if self.motion is not None else None
        return flags if isinstance(flags, str) else self._resume_flags

    def shutdown(self, park: bool = True) -> None:
        """Safe end: park the arms (if ``park`` and no axis reports a fault), then torque off. Never raises. The
        parking move checks ``motion.cancel`` (a no-op unless a capture set it: a second Ctrl-C aborts it)."""
        m = self.motion
        if m is None:
            return
        try:
            if park and m.healthy():
                self.park(check_cancel=True)
                log.info("arms parked at (%g, %g)", self.cfg.light.park_deg, self.cfg.det_axis.park_deg)
            elif park:
                log.warning("arms not parked: an axis reports a fault or its port is gone")
        except BaseException as e:  # noqa: BLE001 - a second Ctrl-C or a failure while parking
            log.error("parking failed: %s", e)
        finally:
            try:
                if m.release() is not False:  # False: the driver said why torque could not be switched off
                    log.info("motion released (torque off)")
            except Exception as e:  # pragma: no cover - best effort
                log.error("torque off failed: %s", e)

    def __enter__(self) -> Bench:
        return self.open()

    def __exit__(self, *exc: object) -> None:
        try:
            self.shutdown(park=True)
        finally:
            self.close()

    # -- operations --------------------------------------------------------------------------------------------
    def _need(self) -> tuple[Any, Any]:
        if self.motion is None or self.detector is None:
            raise DeviceError("the bench is not open: use `with Bench.from_config(...) as bench:` or bench.open()")
        return self.motion, self.detector

    def move(self, theta_i_deg: float, theta_o_deg: float, check_cancel: bool = True) -> None:
        """Move both arms at once to (theta_i, theta_o) and wait until in position. Refuses unmeasurable goals
        outside the soft limits or in the collision zone."""
        motion, _ = self._need()
        why = self.geometry.reason(theta_i_deg, theta_o_deg)
        if why is not None and why.reason is not Reason.BLIND_SPOT:
            raise DeviceError(f"refusing to move to ({theta_i_deg:g}, {theta_o_deg:g}): {why}")
        motion.move({"light": theta_i_deg, "detector": theta_o_deg}, check_cancel=check_cancel)

    def park(self, check_cancel: bool = False) -> None:
        """Move the arms to their ``park_deg`` (light and detector at once)."""
        motion, _ = self._need()
        motion.move({"light": self.cfg.light.park_deg, "detector": self.cfg.det_axis.park_deg},
                    check_cancel=check_cancel)

    def positions(self) -> Point:
        """Present (theta_i, theta_o) in degrees."""
        motion, _ = self._need()
        p = motion.positions()
        return (p["light"], p["detector"])

    def read(self, repeats: int | None = None) -> Reading:
        """Detector reading with the source on: mean and std per channel in counts at the reference setting.

        With ``[detector].auto_range`` (the default) a reading that saturates, or comes near it, is taken again at
        less sensitive settings (lower gains, shorter integration times) as a capture's is, and converted to the
        reference setting (the configured integration time at the highest gain): its mean may then exceed the
        saturation, and ``saturated`` is 0. The darks this needs are measured once (source off; the reference
        setting's is the last :meth:`dark`, else measured when first needed). Without auto-ranging a saturated
        reading is returned as read, with a :class:`~acquisition.errors.SaturationWarning`: its mean is only a
        lower bound. Raises :class:`DeviceError` if even the least sensitive setting saturates."""
        _, det = self._need()
        n = repeats or self.cfg.detector.repeats
        if not self.cfg.detector.auto_range:
            rd = det.read(n)
            if rd.saturated:
                warnings.warn(f"Bench.read: {rd.saturated} of {rd.n} repeats saturated at {det.saturation:g} counts: "
                              "the mean is clipped (a lower bound); lower [detector].integration_time_s or the gain, "
                              "or set [detector].auto_range = true", SaturationWarning, stacklevel=2)
            return rd
        ranger = self._auto_ranger(det)
        try:
            rg = ranger.read(n, "Bench.read")
        finally:
            ranger.restore(keep_start=True)  # the detector at the reference setting for dark() and capture()
        if rg.ranged:
            log.info("Bench.read: auto-ranged to t_int = %g s%s, converted to the reference setting",
                     rg.integration_time_s, "" if rg.gain is None else f", gain {rg.gain:g}")
        return rg.reading

    def dark(self, repeats: int | None = None) -> Reading:
        """Detector reading with the source off (raw counts), at the reference setting (a later auto-ranged
        :meth:`read` converts with it)."""
        _, det = self._need()
        if self._ranger is not None:
            self._ranger.restore(keep_start=True)
        rd = det.dark(repeats or self.cfg.detector.dark_repeats)
        self._ref_dark = rd
        if self._ranger is not None:
            self._ranger.ref_dark = rd
        return rd

    def _auto_ranger(self, det: Any) -> AutoRanger:
        """The auto-ranging of :meth:`read` (one per opening of the bench)."""
        if self._ranger is None:
            d = self.cfg.detector
            self._ranger = AutoRanger(det, d.integration_time_s, d.min_integration_time_s,
                                      read_dark=lambda: det.dark(d.dark_repeats), retries=self.cfg.motion.retries,
                                      gains=d.gains)
            self._ranger.ref_dark = self._ref_dark
        return self._ranger

    def settle(self) -> None:
        """Wait ``[motion].settle_s`` of bench time."""
        _, det = self._need()
        det.dwell(self.cfg.motion.settle_s)

    def now(self) -> float:
        """Bench time (s): the controller's clock (simulated time on the simulator) if it has one, else wall
        time since the bench was opened."""
        if self.detector is not None and self.detector.has_time:
            t = self.detector.time()
            if t is not None:
                return t
        return time.monotonic() - self._wall0

    @property
    def has_clock(self) -> bool:
        return self.detector is not None and self.detector.has_time

    def devices(self) -> Devices:
        """The bench as the engine sees it (:mod:`acquisition.devices.protocols`): the arms, the detector, the clock."""
        _, det = self._need()
        return Devices(_BenchAxes(self), det, _BenchClock(self))

    def capture(self, plan: Plan | None = None, out: str | Path | None = None, resume: bool = False,
                progress: bool | None = None, handle_signals: bool = True,
                points_plan: Any = None, force: bool = False, live: bool = False):  # -> CaptureResult
        """Capture ``plan`` (default: the config's) into ``out``/slice.csv (:class:`acquisition.run.capture.RunEngine`).

        Opens the bench if needed (and then closes it again). Returns a :class:`~acquisition.run.record.CaptureResult`
        (``result.ok``; ``result.raise_for_status()``). ``points_plan``: the plan that measures the points
        (default :func:`acquisition.plans.measure_points`; e.g. ``examples/reference_every_n.py``). A resume first
        measures the last recorded points again and stops (``result.exit_code`` 2) if the sample does not read as
        recorded; ``force``: go on all the same (a deliberate change, recorded in capture.json); ``live``: write
        ``out``/progress.json for a live view (acquisition.live).
        """
        from acquisition.run.capture import RunEngine

        if out is None:
            out = Path("out") / time.strftime("capture-%Y%m%d-%H%M%S")
        eng = RunEngine(self, plan if plan is not None else self.plan(), out, resume=resume, progress=progress,
                        handle_signals=handle_signals, points_plan=points_plan, force=force, live=live)
        return eng.run()


class _BenchAxes:
    """:class:`~acquisition.devices.protocols.Axes` of a bench: both arms at once, refusing unreachable goals."""

    def __init__(self, bench: Bench) -> None:
        self.bench = bench

    def set(self, theta_i_deg: float, theta_o_deg: float) -> MoveStatus:
        self.bench.move(theta_i_deg, theta_o_deg)  # returns once both arms are in position and not moving
        return MoveStatus(True, True, (theta_i_deg, theta_o_deg))

    def check_value(self, theta_i_deg: float, theta_o_deg: float) -> str | None:
        return self.bench.geometry.reason(theta_i_deg, theta_o_deg)

    def stop(self) -> None:
        if self.bench.motion is not None:
            self.bench.motion.stop()

    def positions(self) -> Point:
        return self.bench.positions()


class _BenchClock:
    """:class:`~acquisition.devices.protocols.Clock` of a bench: its own clock, waiting on the controller."""

    def __init__(self, bench: Bench) -> None:
        self.bench = bench

    def now(self) -> float:
        return self.bench.now()

    def dwell(self, seconds: float) -> None:
        _, det = self.bench._need()
        det.dwell(seconds)


def _prompt_swap(which: str) -> None:  # pragma: no cover - interactive
    what = "the white reference" if which == "REF" else "the sample"
    input(f"No sample changer: mount {what} now, then press Enter to continue... ")

