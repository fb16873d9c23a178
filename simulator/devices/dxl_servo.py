"""A virtual Dynamixel X-series servo: its control table (a ``bytearray`` of 148 bytes, little-endian items: EEPROM
lock while torque is on, read-only items, value ranges and position limits, Hardware Error Status with the alert
bit) and the motion of its axis (a trapezoidal profile from Profile Velocity/Acceleration in simulated time). The
bus that routes instructions to servos is :mod:`.dxl_device`.
"""

from __future__ import annotations

import logging
import struct
from collections.abc import Callable
from dataclasses import dataclass

from reconstruction.schema.bench import Axis
from simulator.devices import dxl_codec as c
from simulator.world.clock import SimClock
from simulator.world.faults import FaultInjector
from simulator.world.motion import AxisMotion, dxl_profile_to_units

log = logging.getLogger("simulator.dxl")

TABLE_SIZE = 148
EEPROM_END = 64  # addresses below this are EEPROM: writable only while torque is off

FIRMWARE_VERSION = 48


@dataclass(frozen=True)
class Item:
    name: str
    addr: int
    size: int
    writable: bool
    default: int = 0
    lo: int | None = None
    hi: int | None = None
    signed: bool = False


_ITEMS = [
    Item("model_number", 0, 2, False),
    Item("model_information", 2, 4, False),
    Item("firmware_version", 6, 1, False, FIRMWARE_VERSION),
    Item("id", 7, 1, True, 1, 0, 252),
    Item("baud_rate", 8, 1, True, 1, 0, 7),
    Item("return_delay_time", 9, 1, True, 250, 0, 254),
    Item("drive_mode", 10, 1, True, 0, 0, 13),
    Item("operating_mode", 11, 1, True, 3, 0, 16),
    Item("secondary_id", 12, 1, True, 255, 0, 255),
    Item("protocol_type", 13, 1, True, 2, 1, 2),
    Item("homing_offset", 20, 4, True, 0, -1044479, 1044479, True),
    Item("moving_threshold", 24, 4, True, 10, 0, 1023),
    Item("temperature_limit", 31, 1, True, 80, 0, 100),
    Item("max_voltage_limit", 32, 2, True, 160, 95, 160),
    Item("min_voltage_limit", 34, 2, True, 95, 95, 160),
    Item("pwm_limit", 36, 2, True, 885, 0, 885),
    Item("current_limit", 38, 2, True, 1193, 0, 1193),
    Item("velocity_limit", 44, 4, True, 200, 0, 1023),
    Item("max_position_limit", 48, 4, True, 4095, 0, 4095),
    Item("min_position_limit", 52, 4, True, 0, 0, 4095),
    Item("startup_configuration", 60, 1, True, 0, 0, 3),
    Item("shutdown", 63, 1, True, 52, 0, 255),
    Item("torque_enable", 64, 1, True, 0, 0, 1),
    Item("led", 65, 1, True, 0, 0, 1),
    Item("status_return_level", 68, 1, True, 2, 0, 2),
    Item("registered_instruction", 69, 1, False),
    Item("hardware_error_status", 70, 1, False),
    Item("velocity_i_gain", 76, 2, True, 1920, 0, 16383),
    Item("velocity_p_gain", 78, 2, True, 100, 0, 16383),
    Item("position_d_gain", 80, 2, True, 0, 0, 16383),
    Item("position_i_gain", 82, 2, True, 0, 0, 16383),
    Item("position_p_gain", 84, 2, True, 800, 0, 16383),
    Item("feedforward_2nd_gain", 88, 2, True, 0, 0, 16383),
    Item("feedforward_1st_gain", 90, 2, True, 0, 0, 16383),
    Item("bus_watchdog", 98, 1, True, 0, 0, 127),
    Item("goal_pwm", 100, 2, True, 0, -885, 885, True),
    Item("goal_current", 102, 2, True, 0, -1193, 1193, True),
    Item("goal_velocity", 104, 4, True, 0, -1023, 1023, True),
    Item("profile_acceleration", 108, 4, True, 0, 0, 32767),
    Item("profile_velocity", 112, 4, True, 0, 0, 32767),
    Item("goal_position", 116, 4, True, 0, -1048575, 1048575, True),
    Item("realtime_tick", 120, 2, False),
    Item("moving", 122, 1, False),
    Item("moving_status", 123, 1, False),
    Item("present_pwm", 124, 2, False, signed=True),
    Item("present_current", 126, 2, False, signed=True),
    Item("present_velocity", 128, 4, False, signed=True),
    Item("present_position", 132, 4, False, signed=True),
    Item("velocity_trajectory", 136, 4, False, signed=True),
    Item("position_trajectory", 140, 4, False, signed=True),
    Item("present_input_voltage", 144, 2, False, 120),
    Item("present_temperature", 146, 1, False, 30),
    Item("backup_ready", 147, 1, False),
]
ITEMS = {it.name: it for it in _ITEMS}
#: byte address -> Item covering it (None for reserved gaps)
_BYTE_ITEM: list[Item | None] = [None] * TABLE_SIZE
for _it in _ITEMS:
    for _a in range(_it.addr, _it.addr + _it.size):
        _BYTE_ITEM[_a] = _it

ADDR = {it.name: it.addr for it in _ITEMS}
DYNAMIC_START = 120  # reads touching [120, 148) see motion state: in fast time they complete pending motion

HW_INPUT_VOLTAGE = 0x01
HW_OVERHEATING = 0x04
HW_ENCODER = 0x08
HW_ELECTRICAL_SHOCK = 0x10
HW_OVERLOAD = 0x20

MODE_POSITION = 3
MODE_EXTENDED = 4
CURRENT_UNIT_MA = 2.69


def _fmt(it: Item) -> str:
    return {1: "b", 2: "h", 4: "i"}[it.size].upper() if not it.signed else {1: "b", 2: "h", 4: "i"}[it.size]


class Servo:
    """One X-series servo: control table + motion of the arm it drives (units = raw encoder units)."""

    def __init__(self, dxl_id: int, model_number: int, clock: SimClock, faults: FaultInjector,
                 axis: Axis | None = None, position: float = 2048.0, *, backlash_units: float = 0.0,
                 ringing_units: float = 0.0, settle_time: float = 0.0, stall_overload_s: float = 1.0) -> None:
        self.clock = clock
        self.faults = faults
        self.axis = axis
        self.model_number = model_number
        self.stall_overload_s = stall_overload_s
        self.table = bytearray(TABLE_SIZE)
        self.motion = AxisMotion(position, backlash=backlash_units, ringing=ringing_units, settle_time=settle_time)
        self._factory_defaults(keep_id=False)
        self.set(ITEMS["id"], dxl_id)
        self._reset_ram()
        self.overload_at: float | None = None
        self.registered: tuple[int, bytes] | None = None
        self.refresh(clock.now())

    # -- raw table access ----------------------------------------------------------------------------------
    def get(self, it: Item) -> int:
        return struct.unpack_from("<" + _fmt(it), self.table, it.addr)[0]

    def set(self, it: Item, value: int) -> None:
        if it.signed:
            lo, hi = -(1 << (8 * it.size - 1)), (1 << (8 * it.size - 1)) - 1
        else:
            lo, hi = 0, (1 << (8 * it.size)) - 1
        struct.pack_into("<" + _fmt(it), self.table, it.addr, int(min(max(value, lo), hi)))

    def __getitem__(self, name: str) -> int:
        return self.get(ITEMS[name])

    def __setitem__(self, name: str, value: int) -> None:
        self.set(ITEMS[name], value)

    @property
    def dxl_id(self) -> int:
        return self.table[7]

    @property
    def torque(self) -> bool:
        return bool(self.table[64])

    @property
    def hw_error(self) -> int:
        return self.table[70]

    def _factory_defaults(self, keep_id: bool = False, keep_baud: bool = False) -> None:
        saved_id, saved_baud = self.table[7], self.table[8]
        for it in _ITEMS:
            self.set(it, it.default)
        self["model_number"] = self.model_number
        if keep_id:
            self.table[7] = saved_id
        if keep_baud:
            self.table[8] = saved_baud

    def _reset_ram(self) -> None:
        """Power-up state of the RAM area: torque off, errors clear, goal = present position."""
        for it in _ITEMS:
            if it.addr >= EEPROM_END and it.writable:
                self.set(it, it.default)
        self.table[70] = 0
        self.table[69] = 0
        now = self.clock.now()
        self.motion.stop(now)
        self["goal_position"] = round(self.motion.motor_position(now)) + self["homing_offset"]
        self.overload_at = None

    # -- dynamic state ---------------------------------------------------------------------------------------
    def pending_event_time(self) -> float:
        """Simulated time at which the current motion is over or an error fires (inf if never)."""
        t = self.motion.settled_time() if self.torque else self.clock.now()
        if self.overload_at is not None:
            t = min(t, self.overload_at)
        return t

    def refresh(self, t: float) -> None:
        """Bring fault events and the read-only dynamic items up to simulated time ``t``."""
        if self.overload_at is not None and t >= self.overload_at:
            self._raise_hw_error(HW_OVERLOAD, self.overload_at)
            self.overload_at = None
        m = self.motion
        offset = self["homing_offset"]
        pos = m.motor_position(t)
        vel = m.motor_velocity(t)
        moving = self.torque and m.moving(t)
        profiling = self.torque and m.profiling(t)
        present = round(pos) + offset
        self["present_position"] = present
        self["position_trajectory"] = round(m.goal if not profiling else pos) + offset
        vel_units = vel * 60.0 / 4096.0 / 0.229  # units/s -> 0.229 rpm units
        self["present_velocity"] = round(vel_units)
        self["velocity_trajectory"] = round(vel_units)
        self["moving"] = 1 if moving else 0
        in_pos = abs(self["goal_position"] - present) <= self["moving_threshold"] and not moving
        prof_type = 0
        if self["profile_velocity"] and self["profile_acceleration"]:
            prof_type = 3
        elif self["profile_velocity"]:
            prof_type = 1
        self["moving_status"] = (1 if in_pos else 0) | (2 if profiling else 0) | (prof_type << 4)
        load = 0
        if self.torque:
            load = 40 + (400 if m.stall_time is not None and t >= m.stall_time else 0) + int(abs(vel_units) * 0.5)
        self["present_current"] = load
        self["present_pwm"] = min(885, load)
        self["realtime_tick"] = int(t * 1000) % 32768
        self["present_temperature"] = 30 + (2 if self.torque else 0)

    def _raise_hw_error(self, bit: int, t: float) -> None:
        self.table[70] |= bit
        log.warning("servo %d: hardware error 0x%02x at t=%.3f s", self.dxl_id, self.table[70], t)
        if self["shutdown"] & bit and self.torque:
            self.table[64] = 0
            self.motion.stop(t)
            self.overload_at = None
            log.warning("servo %d: torque off by Shutdown", self.dxl_id)

    def status_error(self, err: int = 0) -> int:
        return err | (c.ERRBIT_ALERT if self.table[70] else 0)

    def physical_deg(self, t: float) -> float | None:
        """Physical arm angle in degrees at ``t`` (arm position incl. backlash/ringing), None without an axis."""
        if self.axis is None:
            return None
        return self.axis.units_to_deg(self.motion.arm_position(t))

    def goal_deg(self, goal_register: int) -> float | None:
        if self.axis is None:
            return None
        return self.axis.units_to_deg(goal_register - self["homing_offset"])

    # -- instructions --------------------------------------------------------------------------------------
    def read(self, addr: int, length: int) -> tuple[int, bytes]:
        if length < 1 or addr + length > TABLE_SIZE:
            return c.ERR_ACCESS, bytes(max(0, min(length, 1024)))
        return 0, bytes(self.table[addr: addr + length])

    def check_write(self, addr: int, data: bytes) -> int:
        """Validate a write without applying it; returns a status error number (0 = fine)."""
        n = len(data)
        if n < 1 or addr + n > TABLE_SIZE:
            return c.ERR_ACCESS
        if addr < EEPROM_END and self.torque:
            return c.ERR_ACCESS
        touched = []
        for a in range(addr, addr + n):
            it = _BYTE_ITEM[a]
            if it is None:
                continue
            if not it.writable:
                return c.ERR_ACCESS
            if it not in touched:
                touched.append(it)
        scratch = bytearray(self.table)
        scratch[addr: addr + n] = data
        for it in touched:
            if it.addr < addr or it.addr + it.size > addr + n:
                continue  # partial item write: accepted without range check
            v = struct.unpack_from("<" + _fmt(it), scratch, it.addr)[0]
            if it.name == "torque_enable" and v == 1 and self.table[70] and not self.torque:
                # X-series refuse torque on while a hardware error is latched
                return c.ERR_RESULT_FAIL
            if it.name == "goal_position":
                mode = self["operating_mode"]
                lo, hi = self["min_position_limit"], self["max_position_limit"]
                if mode == MODE_POSITION and not lo <= v <= hi:
                    return c.ERR_DATA_LIMIT
                if not it.lo <= v <= it.hi:
                    return c.ERR_DATA_RANGE
                continue
            if it.lo is not None and not it.lo <= v <= it.hi:
                return c.ERR_DATA_RANGE
            if it.name == "operating_mode" and v not in (0, 1, 3, 4, 5, 16):
                return c.ERR_DATA_RANGE
        return 0

    def apply_write(self, addr: int, data: bytes, start_motion: bool = True) -> None:
        """Apply a validated write, with side effects (torque on/off, goal -> motion)."""
        t = self.clock.now()
        self.refresh(t)
        was_torque = self.torque
        self.table[addr: addr + len(data)] = data
        end = addr + len(data)
        if addr <= 64 < end:
            if self.torque and not was_torque:
                present = round(self.motion.motor_position(t))
                self.motion.stop(t)
                self["goal_position"] = present + self["homing_offset"]
            elif was_torque and not self.torque:
                self.motion.stop(t)
                self.overload_at = None
        if addr < 120 and end > 116 and self.torque and start_motion:
            self._start_move(self["goal_position"], t)
        self.refresh(t)

    def _start_move(self, goal_register: int, t: float) -> None:
        if self["operating_mode"] not in (MODE_POSITION, MODE_EXTENDED):
            return
        target = goal_register - self["homing_offset"]
        v, a = dxl_profile_to_units(self["profile_velocity"], self["profile_acceleration"])
        if abs(target - self.motion.motor_position(t)) < 0.5 and not self.motion.moving(t):
            self.motion.start(target, t, v, a)
            return
        stall = self.faults.stall_fraction()
        self.motion.start(target, t, v, a, stall_fraction=stall)
        self.overload_at = None
        if stall is not None:
            self.overload_at = self.motion.stall_time + self.stall_overload_s
            log.warning("servo %d: fault: stall at t=%.3f s", self.dxl_id, self.motion.stall_time)
        frac = self.faults.overload_fraction()
        if frac is not None:
            t_ol = t + frac * self.motion.profile.duration
            self.overload_at = t_ol if self.overload_at is None else min(self.overload_at, t_ol)
            log.warning("servo %d: fault: overload scheduled at t=%.3f s", self.dxl_id, t_ol)

    def reboot(self) -> None:
        """Reboot: RAM to power-up defaults (torque off), hardware error cleared, position kept."""
        t = self.clock.now()
        self.refresh(t)
        self._reset_ram()
        self.registered = None
        self.refresh(t)

    def factory_reset(self, option: int) -> int:
        if self.torque:
            return c.ERR_ACCESS
        if option not in (0x01, 0x02, 0xFF):
            return c.ERR_DATA_RANGE
        self._factory_defaults(keep_id=option in (0x01, 0x02), keep_baud=option == 0x02)
        if option == 0xFF:
            self.table[7] = 1
        self._reset_ram()
        self.refresh(self.clock.now())
        return 0


CollisionCheck = Callable[[dict[str, float]], bool]


