"""Dynamixel X-series arms over Protocol 2.0 with the real ``dynamixel_sdk``.

Set-up per servo: ping and check the model number; read Hardware Error Status (a fault latched from an earlier
run is cleared with a Reboot, and logged); with torque off write operating mode 3 (position), the soft limits
as Min/Max Position Limit and the profile velocity/acceleration; then torque on. A move writes the goal positions
of all arms in one GroupSyncWrite packet and polls one GroupSyncRead (Moving .. Present Position) until no arm
is Moving and every arm lies within the tolerance; an alert bit in any status packet makes the driver read
Hardware Error Status and stop safely (:class:`HardwareError`).

Every transaction is retried a bounded number of times on timeouts, corrupt replies and CRC-error statuses,
then raises :class:`CommError` naming the servo and the failure. The SDK's ``port.is_using`` flag stays set if
an exception escapes mid-transaction (e.g. a vanished USB adapter): every SDK call here is guarded so the flag
is released whatever happens.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable
from typing import Any

from dynamixel_sdk import (
    COMM_SUCCESS,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from acquisition.devices.driver import Driver, Opening, Port
from acquisition.errors import PORT_ERRORS, CommError, DeviceError, HardwareError, PortError, port_reason
from reconstruction.schema.bench import DXL_MODELS, Axis, MotionTable

log = logging.getLogger("acquisition.dynamixel")

__all__ = ["DynamixelAxes", "hardware_error_text"]

ADDR_MODEL = 0
ADDR_OPERATING_MODE = 11
ADDR_MAX_POSITION_LIMIT = 48
ADDR_MIN_POSITION_LIMIT = 52
ADDR_TORQUE_ENABLE = 64
ADDR_HW_ERROR = 70
ADDR_PROFILE_ACCELERATION = 108
ADDR_PROFILE_VELOCITY = 112
ADDR_GOAL_POSITION = 116
ADDR_MOVING = 122
ADDR_PRESENT_POSITION = 132
STATE_ADDR, STATE_LEN = ADDR_MOVING, ADDR_PRESENT_POSITION + 4 - ADDR_MOVING  # Moving .. Present Position

MODE_POSITION = 3
ERRBIT_ALERT = 0x80
ERR_CRC = 3

HW_BITS = {0: "input voltage", 2: "overheating", 3: "motor encoder", 4: "electrical shock", 5: "overload"}


def hardware_error_text(bits: int) -> str:
    """Names of the set bits of Hardware Error Status."""
    names = [name for b, name in HW_BITS.items() if bits & (1 << b)]
    return ", ".join(names) or f"0x{bits:02x}"


def _le32(v: int) -> list[int]:
    return list(int(v).to_bytes(4, "little", signed=True))


def _s32(b: bytes | list[int]) -> int:
    return int.from_bytes(bytes(b), "little", signed=True)


class DynamixelAxes:
    """The arms on one Dynamixel bus; angles in degrees, positions in servo units (0.088 deg)."""

    def __init__(self, port: str, baudrate: int, axes: dict[str, Axis], motion: MotionTable,
                 latency_ms: float | None = None) -> None:
        self.port_name = port
        #: the adapter's latency (ms) in the SDK's reply deadline, 2 x latency + 2 ms + the bytes' time; None: the
        #: SDK's 16 ms (an FTDI adapter's default latency timer)
        self.latency_ms = latency_ms
        self.baudrate = baudrate
        self.axes = axes
        self.motion = motion
        self.retries = motion.retries
        self.ph = PacketHandler(2.0)
        self.port: PortHandler | None = None
        self.goal: dict[str, float] = {}
        self.hw_errors: dict[str, int] = {}
        self.port_dead = False
        self.torque_on = False
        self.cancel: Callable[[], None] = lambda: None
        self.stats = {"transactions": 0, "retries": 0}

    # -- guarded SDK calls --------------------------------------------------------------------------------------
    def _who(self, dxl_id: int) -> str:
        for name, ax in self.axes.items():
            if ax.id == dxl_id:
                return f"servo {dxl_id} ({name} arm)" if name != "stage" else f"servo {dxl_id} (stage)"
        return f"servo {dxl_id}"

    def _guarded(self, fn: Callable[..., Any], *args: Any) -> Any:
        """Call an SDK function; whatever happens, release ``port.is_using``."""
        assert self.port is not None
        try:
            return fn(*args)
        except PORT_ERRORS as e:
            self.port_dead = True
            raise CommError(f"Dynamixel bus on {self.port_name}: port failed ({e}); is the USB adapter still "
                            "connected and powered?") from None
        finally:
            self.port.is_using = False

    def _txrx(self, what: str, dxl_id: int, fn: Callable[..., Any], *args: Any, allow_alert: bool = False) -> Any:
        """Run a unicast transaction with bounded retries; returns the SDK's return tuple."""
        problem = ""
        for attempt in range(self.retries + 1):
            self.stats["transactions"] += 1
            if attempt:
                self.stats["retries"] += 1
                log.info("%s: retrying %s (attempt %d): %s", self._who(dxl_id), what, attempt + 1, problem)
            ret = self._guarded(fn, self.port, dxl_id, *args)
            result, error = ret[-2], ret[-1]
            if result != COMM_SUCCESS:
                problem = self.ph.getTxRxResult(result)
                continue
            if error & 0x7F == ERR_CRC:
                problem = "the servo saw a CRC error in our packet"
                continue
            if error & ERRBIT_ALERT and not allow_alert:
                self._on_alert([dxl_id])
            if error & 0x7F:
                raise DeviceError(f"{self._who(dxl_id)}: {what} refused: "
                                  f"{self.ph.getRxPacketError(error & 0x7F).replace('[RxPacketError] ', '')}")
            return ret
        raise CommError(f"{self._who(dxl_id)} on {self.port_name}: {what} failed after {self.retries + 1} "
                        f"attempts: {problem.replace('[TxRxResult] ', '')}")

    def _write(self, dxl_id: int, addr: int, size: int, value: int, what: str) -> None:
        fn = {1: self.ph.write1ByteTxRx, 2: self.ph.write2ByteTxRx, 4: self.ph.write4ByteTxRx}[size]
        self._txrx(what, dxl_id, fn, addr, value)

    def _read(self, dxl_id: int, addr: int, size: int, what: str, allow_alert: bool = False) -> int:
        fn = {1: self.ph.read1ByteTxRx, 2: self.ph.read2ByteTxRx, 4: self.ph.read4ByteTxRx}[size]
        return int(self._txrx(what, dxl_id, fn, addr, allow_alert=allow_alert)[0])

    # -- set-up -------------------------------------------------------------------------------------------------
    def connect(self) -> None:
        """Open the bus, check every servo and configure it (see the module docstring)."""
        self.port = PortHandler(self.port_name) if self.latency_ms is None else \
            _LatentPort(self.port_name, self.latency_ms)
        try:
            ok = self.port.openPort()
        except PORT_ERRORS as e:
            why = port_reason(e)
            raise PortError(f"Dynamixel bus: cannot open {self.port_name!r}: {why}", self.port_name, why) from None
        if not ok or not self.port.setBaudRate(self.baudrate):
            raise CommError(f"Dynamixel bus: cannot open {self.port_name!r} at {self.baudrate} baud")
        for name, ax in self.axes.items():
            dxl_id = int(ax.id)
            model = int(self._txrx("ping", dxl_id, self.ph.ping, allow_alert=True)[0])
            want = DXL_MODELS[str(ax.model)]
            if model != want:
                raise DeviceError(f"{self._who(dxl_id)}: model number {model}, but the config says {ax.model} "
                                  f"({want}); check [axes.{name}].id and .model")
            hw = self._read(dxl_id, ADDR_HW_ERROR, 1, "read Hardware Error Status", allow_alert=True)
            if hw:
                log.warning("%s: hardware error latched from before (%s); rebooting it", self._who(dxl_id),
                            hardware_error_text(hw))
                self._reboot(dxl_id)
            self._write(dxl_id, ADDR_TORQUE_ENABLE, 1, 0, "torque off")
            if self._read(dxl_id, ADDR_OPERATING_MODE, 1, "read Operating Mode") != MODE_POSITION:
                self._write(dxl_id, ADDR_OPERATING_MODE, 1, MODE_POSITION, "set position mode")
            lo, hi = sorted((ax.deg_to_units(ax.min_deg), ax.deg_to_units(ax.max_deg)))
            lo_u, hi_u = max(0, int(lo // 1)), min(4095, -int(-hi // 1))  # rounded outwards
            # EEPROM items: written only when they differ (EEPROM has a limited number of write cycles)
            if self._read(dxl_id, ADDR_MIN_POSITION_LIMIT, 4, "read Min Position Limit") != lo_u:
                self._write(dxl_id, ADDR_MIN_POSITION_LIMIT, 4, lo_u, "set Min Position Limit")
            if self._read(dxl_id, ADDR_MAX_POSITION_LIMIT, 4, "read Max Position Limit") != hi_u:
                self._write(dxl_id, ADDR_MAX_POSITION_LIMIT, 4, hi_u, "set Max Position Limit")
            self._write(dxl_id, ADDR_PROFILE_ACCELERATION, 4, self.motion.profile_acceleration,
                        "set Profile Acceleration")
            self._write(dxl_id, ADDR_PROFILE_VELOCITY, 4, self.motion.profile_velocity, "set Profile Velocity")
            pos = ax.units_to_deg(_s32(_le32(self._read(dxl_id, ADDR_PRESENT_POSITION, 4, "read position"))))
            if not ax.within(pos, 1.0):
                log.warning("%s: at %.2f deg, outside the soft limits [%g, %g]", self._who(dxl_id), pos,
                            ax.min_deg, ax.max_deg)
        self.enable()
        if "stage" in self.axes:
            self.move({"stage": self.axes["stage"].park_deg})

    def enable(self) -> None:
        """Torque on for every servo (refused while a hardware error is latched: reconnect to clear it)."""
        if self.hw_errors:
            name, bits = next(iter(self.hw_errors.items()))
            raise HardwareError(f"{self._who(int(self.axes[name].id))}: hardware error ({hardware_error_text(bits)}) "
                                "latched; reconnect (which reboots the servo) before moving")
        for ax in self.axes.values():
            self._write(int(ax.id), ADDR_TORQUE_ENABLE, 1, 1, "torque on")
        self.torque_on = True

    def _reboot(self, dxl_id: int) -> None:
        self._txrx("reboot", dxl_id, self.ph.reboot, allow_alert=True)
        deadline = time.monotonic() + 3.0
        while True:
            time.sleep(0.05)
            ret = self._guarded(self.ph.ping, self.port, dxl_id)
            if ret[1] == COMM_SUCCESS:
                break
            if time.monotonic() > deadline:
                raise CommError(f"{self._who(dxl_id)}: no answer after reboot")
        hw = self._read(dxl_id, ADDR_HW_ERROR, 1, "read Hardware Error Status", allow_alert=True)
        if hw:
            raise HardwareError(f"{self._who(dxl_id)}: hardware error ({hardware_error_text(hw)}) persists after "
                                "a reboot; check the servo, its power and its load")

    # -- state --------------------------------------------------------------------------------------------------
    def _sync_state(self) -> dict[str, tuple[int, int, int]]:
        """GroupSyncRead of Moving .. Present Position: name -> (moving, moving_status, present_units)."""
        ids = {int(ax.id): name for name, ax in self.axes.items()}
        problem = ""
        for attempt in range(self.retries + 1):
            if attempt:
                self.stats["retries"] += 1
                log.info("Dynamixel bus: retrying sync read (attempt %d): %s", attempt + 1, problem)
            self.stats["transactions"] += 1
            gsr = GroupSyncRead(self.port, self.ph, STATE_ADDR, STATE_LEN)
            for i in ids:
                gsr.addParam(i)
            result = self._guarded(gsr.txPacket)
            if result != COMM_SUCCESS:
                problem = self.ph.getTxRxResult(result)
                continue
            out: dict[str, tuple[int, int, int]] = {}
            alerts = []
            for i, name in ids.items():
                data, result, error = self._guarded(self.ph.readRx, self.port, i, STATE_LEN)
                if result != COMM_SUCCESS or len(data) != STATE_LEN:
                    problem = f"{self._who(i)}: {self.ph.getTxRxResult(result)}"
                    break
                if error & 0x7F == ERR_CRC:
                    problem = f"{self._who(i)}: CRC error reported"
                    break
                if error & ERRBIT_ALERT:
                    alerts.append(i)
                out[name] = (data[0], data[1], _s32(data[ADDR_PRESENT_POSITION - STATE_ADDR:]))
            else:
                if alerts:
                    self._on_alert(alerts)
                return out
        raise CommError(f"Dynamixel bus on {self.port_name}: reading the arm positions failed after "
                        f"{self.retries + 1} attempts: {problem.replace('[TxRxResult] ', '')}")

    def positions(self) -> dict[str, float]:
        """Present angle of every axis (deg)."""
        return {name: self.axes[name].units_to_deg(u) for name, (_, _, u) in self._sync_state().items()}

    def _on_alert(self, ids: list[int]) -> None:
        """An alert bit was seen: read Hardware Error Status, stop everything, raise HardwareError."""
        msgs = []
        for i in ids:
            try:
                hw = self._read(i, ADDR_HW_ERROR, 1, "read Hardware Error Status", allow_alert=True)
            except Exception as e:  # pragma: no cover - reporting what we can
                msgs.append(f"{self._who(i)}: alert, Hardware Error Status unreadable ({e})")
                continue
            name = next((n for n, ax in self.axes.items() if ax.id == i), str(i))
            self.hw_errors[name] = hw
            msgs.append(f"{self._who(i)}: hardware error: {hardware_error_text(hw)}")
        self.release()
        raise HardwareError("; ".join(msgs) + ". All servos were switched to torque off. Check the arms for an "
                            "obstruction or overload; a resume reboots the servo to clear the error")

    # -- motion -------------------------------------------------------------------------------------------------
    def _send_goals(self, goals: dict[str, float]) -> None:
        gsw = GroupSyncWrite(self.port, self.ph, ADDR_GOAL_POSITION, 4)
        for name, deg in goals.items():
            gsw.addParam(int(self.axes[name].id), _le32(round(self.axes[name].deg_to_units(deg))))
        problem = ""
        for attempt in range(self.retries + 1):
            result = self._guarded(gsw.txPacket)
            if result == COMM_SUCCESS:
                return
            problem = self.ph.getTxRxResult(result)
            log.info("Dynamixel bus: retrying goal sync write (attempt %d): %s", attempt + 2, problem)
        raise CommError(f"Dynamixel bus on {self.port_name}: cannot send the goal positions: {problem}")

    def move(self, goals: dict[str, float], check_cancel: bool = True) -> None:
        """Move the named axes to ``goals`` (deg) in one sync write; wait until not Moving and in position."""
        for name, deg in goals.items():
            ax = self.axes[name]
            if not ax.within(deg):
                raise DeviceError(f"{self._who(int(ax.id))}: goal {deg:g} deg outside the soft limits "
                                  f"[{ax.min_deg:g}, {ax.max_deg:g}]")
        if not self.torque_on:
            self.enable()
        self.goal.update(goals)
        self._send_goals(goals)
        tol = self.motion.tolerance_deg
        t_end = time.monotonic() + self.motion.timeout_s
        resends = 0
        while True:
            if check_cancel:
                self.cancel()
            state = self._sync_state()
            moving = [n for n, (mv, _, _) in state.items() if mv]
            off = {n: self.axes[n].units_to_deg(state[n][2]) for n in goals
                   if abs(self.axes[n].units_to_deg(state[n][2]) - goals[n]) > tol}
            if not moving and not off:
                return
            if not moving:
                if resends >= self.retries:
                    n, deg = next(iter(off.items()))
                    raise DeviceError(f"{self._who(int(self.axes[n].id))}: stopped at {deg:.3f} deg, not at its "
                                      f"goal {goals[n]:.3f} deg (tolerance {tol:g}) after {resends} re-sends")
                resends += 1
                log.warning("Dynamixel bus: arms idle but not in position (%s); re-sending the goals", off)
                self._send_goals(goals)
                continue
            if time.monotonic() > t_end:
                n = moving[0]
                self.release()
                raise DeviceError(f"{self._who(int(self.axes[n].id))}: still moving after "
                                  f"{self.motion.timeout_s:g} s (goal {goals.get(n)}); all servos torque off")
            if self.motion.poll_interval_s:
                time.sleep(self.motion.poll_interval_s)

    def stop(self) -> None:
        """Hold every arm where it is (goal = present position), best effort."""
        try:
            pos = self.positions()
            self._send_goals(pos)
        except Exception as e:
            log.warning("Dynamixel bus: stop failed: %s", e)

    def release(self) -> bool:
        """Torque off on every servo (best effort, each tried even if another fails). False when none could be
        confirmed (the bus is gone: the log says to cut the servo power), so nobody reports the motion released."""
        if self.port is None:
            return True
        if self.port_dead:
            log.error("Dynamixel bus on %s is gone: cannot switch torque off; cut the servo power", self.port_name)
            return False
        self.torque_on = False
        confirmed = 0
        for ax in self.axes.values():
            for _ in range(self.retries + 1):
                try:
                    ret = self._guarded(self.ph.write1ByteTxRx, self.port, int(ax.id), ADDR_TORQUE_ENABLE, 0)
                except CommError as e:
                    log.warning("%s: torque off failed: %s", self._who(int(ax.id)), e)
                    break
                if ret[0] == COMM_SUCCESS:
                    confirmed += 1
                    break
            else:
                log.warning("%s: torque off not confirmed", self._who(int(ax.id)))
        return confirmed > 0

    def healthy(self) -> bool:
        """False once a hardware error was seen (then the arms must not be moved) or the port failed."""
        return not self.hw_errors and not self.port_dead

    def close(self) -> None:
        if self.port is not None:
            try:
                self.port.closePort()
            except Exception:  # pragma: no cover
                pass


class _LatentPort(PortHandler):
    """The SDK's port with another adapter latency in its reply deadline (``setPacketTimeout``): the SDK's own
    formula, ``tx_time_per_byte * length + 2 * latency + 2`` ms, with ``latency_ms`` for its 16 ms constant. A
    simulated bench's servos answer from a process that a loaded machine may not schedule within 34 ms."""

    def __init__(self, port_name: str, latency_ms: float) -> None:
        super().__init__(port_name)
        self.latency_ms = latency_ms

    def setPacketTimeout(self, packet_length: int) -> None:  # noqa: N802 (the SDK's name)
        self.packet_start_time = self.getCurrentTime()
        self.packet_timeout = self.tx_time_per_byte * packet_length + 2.0 * self.latency_ms + 2.0


#: The adapter latency (ms) a simulated Dynamixel bus is given in the SDK's reply deadline (16 ms on hardware):
#: the simulator is a process of its own, which a loaded 2-core machine may not schedule within the SDK's 34 ms.
SIMULATED_DXL_LATENCY_MS = 100.0


def _open(o: Opening) -> DynamixelAxes:
    """The arms on the Dynamixel bus of ``o`` (a simulated bus with a deadline a loaded machine can keep)."""
    return DynamixelAxes(o.ports["dynamixel"], o.cfg.bench.dynamixel_baudrate, o.cfg.axes, o.cfg.motion,
                         latency_ms=SIMULATED_DXL_LATENCY_MS if o.simulated else None)


#: ``[bench].motion = "dynamixel"``: servo arms on a Dynamixel bus (:mod:`acquisition.devices.registry`).
DRIVER = Driver("dynamixel", "motion", MotionTable,
                (Port("dynamixel", "[bench].dynamixel_port", "[bench].dynamixel_baudrate", "Dynamixel bus (U2D2)"),),
                _open)
