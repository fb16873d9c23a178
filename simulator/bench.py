"""The virtual bench: clock, physics, Dynamixel bus and/or serial controller built from one config."""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

import numpy as np

from simulator.config import BenchConfig
from simulator.devices.dxl_device import DynamixelBus
from simulator.devices.dxl_servo import Servo
from simulator.devices.grbl import VirtualGrbl
from simulator.devices.serial_controller import SerialController, StepperAxis
from simulator.devices.usb_detectors import UsbDetector
from simulator.world.clock import SimClock
from simulator.world.faults import FaultInjector
from simulator.world.physics import BRDF, BenchPhysics

log = logging.getLogger("simulator.bench")

class VirtualBench:
    """Everything behind the two ports. Thread-safe: :meth:`process` serialises access with one lock.

    Random streams (all from ``[simulator].seed``): detector noise, Dynamixel comm faults, serial comm faults,
    motion faults, detector saturation faults - independent, so enabling one fault does not change another. Each
    fault decision is drawn per transaction (reply, byte, move, reading) from its stream. ``attempt`` (the number
    of earlier runs of a resumed capture, ``gonio-sim serve --attempt N``) selects streams of their own
    (``SeedSequence([seed, attempt])``; attempt 0 is ``SeedSequence(seed)``), so a resumed capture does not replay
    the faults that stopped the run before it.
    """

    def __init__(self, cfg: BenchConfig, material: BRDF | None = None, reference: BRDF | None = None,
                 attempt: int = 0, arm_source: Callable[[float], tuple[float, float]] | None = None) -> None:
        self.cfg = cfg
        s = cfg.sim
        self.clock = SimClock(s.time_scale)
        self.lock = threading.RLock()
        self.attempt = int(attempt)
        entropy = int(s.seed) if self.attempt == 0 else [int(s.seed), self.attempt]
        seeds = np.random.SeedSequence(entropy).spawn(5)
        rngs = [np.random.default_rng(sq) for sq in seeds]
        f = s.faults
        self.dxl_comm_faults = FaultInjector(f, rngs[1])
        self.serial_comm_faults = FaultInjector(f, rngs[2], comm=f.serial_comm_faults)
        self.motion_faults = FaultInjector(f, rngs[3])
        self.detector_faults = FaultInjector(f, rngs[4])
        self.physics = BenchPhysics(cfg, rngs[0], self.detector_faults, material=material, reference=reference)
        self.vanished: set[str] = set()

        self.bus: DynamixelBus | None = None
        self.grbl: VirtualGrbl | None = None
        self.arm_source = arm_source  # the arms' angles from outside (grbl-sim's step output), a detector-only bench
        steppers: list[StepperAxis] = []
        if arm_source is not None:
            pass
        elif cfg.motion == "grbl":
            self.grbl = VirtualGrbl(cfg, self.clock)
        elif cfg.motion == "dynamixel":
            servos = []
            for name, ax in cfg.axes.items():
                if not isinstance(ax.id, int):
                    raise ValueError(f"[axes.{name}].id must be an integer Dynamixel ID on a Dynamixel bench")
                upd = abs(ax.units_per_deg)
                servos.append(Servo(
                    ax.id, ax.model_number, self.clock, self.motion_faults, axis=ax,
                    position=ax.deg_to_units(ax.park_deg),
                    backlash_units=s.backlash_deg * upd, ringing_units=s.settle_ringing_deg * upd,
                    settle_time=s.settle_time_s, stall_overload_s=f.stall_overload_s,
                ))
            self.bus = DynamixelBus(servos, self.clock, self.dxl_comm_faults, collision_check=self.collides)
        else:
            steppers = [StepperAxis(ax, s, self.clock) for ax in cfg.axes.values()]
        self.controller = SerialController(
            cfg, self.clock, self.physics, self.serial_comm_faults, self.motion_faults, steppers,
            arm_angles=self.arm_angles if self.bus is not None or self.grbl is not None or arm_source is not None
            else None, collision=self.collides,
        )
        #: the detector that is not the board's (seabreeze, pm100), on its own port for its stand-in
        self.usb = UsbDetector(cfg, self.clock, self.physics, self.arm_angles) \
            if cfg.detector.type in ("seabreeze", "pm100") else None

    # -- geometry --------------------------------------------------------------------------------------------
    def collides(self, goals_deg: dict[str, float]) -> bool:
        """True if light and detector goals are closer than ``min_separation_deg`` (|theta_i + theta_o|)."""
        ti = goals_deg.get("light")
        to = goals_deg.get("detector")
        if ti is None or to is None:
            return False
        return abs(ti + to) < self.cfg.bench.min_separation_deg

    def arm_angles(self, t: float | None = None) -> tuple[float, float]:
        """Physical (theta_i, theta_o) in degrees at simulated time ``t`` (default: now)."""
        t = self.clock.now() if t is None else t
        if self.arm_source is not None:
            return self.arm_source(t)
        if self.grbl is not None:
            return self.grbl.arm_angles(t)
        if self.bus is not None:
            ang = {}
            for sv in self.bus.servos:
                if sv.axis is not None:
                    ang[sv.axis.name] = sv.physical_deg(t)
            return ang.get("light", 0.0), ang.get("detector", 0.0)
        return self.controller.arm_angles(t)

    # -- ports -----------------------------------------------------------------------------------------------
    @property
    def ports(self) -> tuple[str, ...]:
        """Names of the ports this bench offers."""
        if self.grbl is not None:
            names = ("serial", "grbl")
        else:
            names = ("dynamixel", "serial") if self.bus is not None else ("serial",)
        return names + ("usb",) if self.usb is not None else names

    def check_vanish(self) -> None:
        """Mark ports as vanished once simulated time passes ``port_vanish_after_s``."""
        f = self.cfg.sim.faults
        if f.port_vanish_after_s > 0 and self.clock.now() >= f.port_vanish_after_s:
            which = set(self.ports) if f.vanish_ports == "all" else {f.vanish_ports}
            new = which - self.vanished
            if new:
                log.warning("fault: port(s) %s vanish at t=%.3f s", sorted(new), self.clock.now())
                self.vanished |= new

    def process(self, port: str, data: bytes) -> bytes:
        """Bytes received on ``port`` -> bytes to send back. Raises nothing (device errors become replies)."""
        out = b""
        while True:
            wait = 0.0
            with self.lock:
                if port in self.vanished:
                    return b""
                dev = {"dynamixel": self.bus, "usb": self.usb, "grbl": self.grbl}.get(port, self.controller)
                if dev is None:
                    return b""
                out += dev.process(data)
                if dev is not self.bus:  # the line devices' replies may take scaled time (world.clock.Paced)
                    wait = dev.take_wait()
            if wait <= 0:
                break
            # scaled time: an integration/dwell takes wall time, slept without holding the lock (the Dynamixel
            # port stays responsive); then the remaining lines of this chunk are handled
            self.clock.advance(wait)
            data = b""
        with self.lock:
            self.check_vanish()
            if port in self.vanished:
                return b""
        return out

    def sim_time(self) -> float:
        """Total simulated time so far (s)."""
        return self.clock.now()
