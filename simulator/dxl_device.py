"""Virtual Dynamixel X-series servos on a Protocol 2.0 bus.

:class:`Servo` holds one control table (a ``bytearray`` of 148 bytes, little-endian items) and the motion of its
axis; :class:`DynamixelBus` frames incoming bytes (:mod:`.dxl_codec`), routes instructions to the servos and
returns the status packets as bytes, exactly as they would appear on the wire.

Modelled: Ping (unicast and broadcast), Read, Write, RegWrite/Action, FactoryReset, Reboot, SyncRead, SyncWrite,
FastSyncRead, BulkRead, FastBulkRead, BulkWrite; CRC check (a unicast packet with a bad CRC gets a CRC-error
status); stuffed and unstuffed instruction packets; EEPROM lock while torque is on (Access Error); read-only
items (Access Error); value ranges (Data Range) and position limits (Data Limit); Status Return Level; Hardware
Error Status with the alert bit (latched until reboot, torque off per Shutdown); Moving, Moving Status, Present
Position/Velocity following a trapezoidal profile from Profile Velocity/Acceleration in simulated time.

Not modelled: baud-rate changes (the pty carries any rate), Return Delay Time (replies are immediate), the
time-based profile bit of Drive Mode, velocity/current/PWM operating modes (goals are stored, nothing moves),
indirect addresses (reads past address 147 give an Access Error).
"""

from __future__ import annotations

import logging
import math
import struct
import time
from collections.abc import Callable
from dataclasses import dataclass

from . import dxl_codec as c
from .clock import SimClock
from .config import AxisConfig
from .faults import FaultInjector
from .motion import AxisMotion, dxl_profile_to_units

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
                 axis: AxisConfig | None = None, position: float = 2048.0, *, backlash_units: float = 0.0,
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


class DynamixelBus:
    """Routes Protocol 2.0 instruction packets to :class:`Servo` objects and produces the status bytes.

    ``collision_check(goals_deg)`` gets the goal angles of all axes after a proposed goal write (axis name ->
    degrees) and returns True when the arms would collide; the write is then refused with a Data Range error plus
    the alert bit, and the servos addressed get an overload hardware error (torque off per Shutdown).
    """

    def __init__(self, servos: list[Servo], clock: SimClock, faults: FaultInjector,
                 collision_check: CollisionCheck | None = None) -> None:
        self.servos = list(servos)
        self.clock = clock
        self.faults = faults
        self.collision_check = collision_check
        self.parser = c.PacketParser()
        self.stats = {"packets": 0, "crc_errors": 0, "replies": 0, "internal_errors": 0}
        self.last_rx = time.monotonic()

    #: A partial packet older than this (wall-clock) is discarded when new bytes arrive (firmware packet timeout).
    PACKET_TIMEOUT_S = 0.1

    def servo(self, dxl_id: int) -> Servo | None:
        for s in self.servos:
            if s.dxl_id == dxl_id:
                return s
        return None

    # -- byte interface ------------------------------------------------------------------------------------
    def process(self, data: bytes) -> bytes:
        """Feed received bytes; return the bytes to transmit (status packets, faults applied). Never raises."""
        out = bytearray()
        now = time.monotonic()
        if self.parser.pending and now - self.last_rx > self.PACKET_TIMEOUT_S:
            log.debug("discarding %d stale bytes of a partial packet", self.parser.pending)
            self.parser.reset()
        self.last_rx = now
        try:
            frames = self.parser.feed(data)
        except Exception:  # pragma: no cover - defensive
            log.exception("parser failure; buffer reset")
            self.parser.reset()
            return b""
        for fr in frames:
            try:
                replies = self.handle_frame(fr)
            except Exception:
                log.exception("device failure on packet %s", fr.raw.hex(" "))
                self.stats["internal_errors"] += 1
                replies = []
            for pkt in replies:
                if self.faults.drop_reply():
                    log.info("fault: dropped status packet from ID %d", pkt[4])
                    continue
                out += self.faults.corrupt(pkt)
                self.stats["replies"] += 1
        return bytes(out)

    # -- instruction dispatch ------------------------------------------------------------------------------
    def handle_frame(self, fr: c.Frame) -> list[bytes]:
        """Execute one framed instruction packet; return the status packets (no faults applied)."""
        self.stats["packets"] += 1
        dxl_id = fr.dxl_id
        unicast = dxl_id != c.BROADCAST_ID
        if not fr.crc_ok:
            self.stats["crc_errors"] += 1
            s = self.servo(dxl_id) if unicast else None
            log.info("CRC error in packet to ID %d", dxl_id)
            return [c.status_packet(dxl_id, s.status_error(c.ERR_CRC))] if s is not None else []
        if not fr.body:
            return []
        inst = fr.body[0]
        if inst == c.INST_STATUS:
            return []  # a status packet (echo or another device): not for us
        if unicast and self.servo(dxl_id) is None:
            return []
        handler = self._HANDLERS.get(inst)
        candidates = fr.params_candidates()
        if handler is None:
            return self._simple_error(dxl_id, c.ERR_INSTRUCTION)
        for params in candidates:
            res = handler(self, dxl_id, params)
            if res is not None:
                return res
        return self._simple_error(dxl_id, c.ERR_DATA_LENGTH)

    def _simple_error(self, dxl_id: int, err: int) -> list[bytes]:
        s = self.servo(dxl_id) if dxl_id != c.BROADCAST_ID else None
        return [c.status_packet(dxl_id, s.status_error(err))] if s is not None else []

    def _targets(self, dxl_id: int) -> list[Servo]:
        if dxl_id == c.BROADCAST_ID:
            return sorted(self.servos, key=lambda s: s.dxl_id)
        s = self.servo(dxl_id)
        return [s] if s is not None else []

    def _reply(self, s: Servo, err: int, params: bytes = b"", level: int = 2) -> list[bytes]:
        """Status packet unless Status Return Level suppresses it (0: ping only, 1: ping+read, 2: all)."""
        if s["status_return_level"] < level:
            return []
        return [c.status_packet(s.dxl_id, s.status_error(err), params)]

    def _prepare_read(self, reads: list[tuple[Servo, int, int]]) -> None:
        """Fast time: reads of motion state complete pending motion; then refresh all servos at one instant."""
        if self.clock.fast:
            target = self.clock.now()
            for s, addr, length in reads:
                if addr + length > DYNAMIC_START:
                    ev = s.pending_event_time()
                    if math.isfinite(ev):
                        target = max(target, ev)
            self.clock.jump_to(target)
        t = self.clock.now()
        for s in self.servos:
            s.refresh(t)

    def _ping(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        t = self.clock.now()
        out = []
        for s in self._targets(dxl_id):
            s.refresh(t)
            out.append(c.status_packet(s.dxl_id, s.status_error(),
                                       struct.pack("<HB", s.model_number, s.table[6])))
        return out

    def _read(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        if len(params) != 4 or dxl_id == c.BROADCAST_ID:
            return None if dxl_id != c.BROADCAST_ID else []
        addr, length = struct.unpack("<HH", params)
        s = self.servo(dxl_id)
        self._prepare_read([(s, addr, length)])
        err, data = s.read(addr, length)
        return self._reply(s, err, data, level=1)

    def _goal_collides(self, writes: list[tuple[Servo, int, bytes]]) -> bool:
        """Would the goal positions after ``writes`` put the arms closer than the minimum separation?"""
        if self.collision_check is None:
            return False
        touched = False
        goals: dict[str, float] = {}
        new_goal = {}
        for s, addr, data in writes:
            if s.axis is not None and s.torque and addr <= 116 and addr + len(data) >= 120:
                scratch = bytearray(s.table)
                scratch[addr: addr + len(data)] = data
                new_goal[s.dxl_id] = struct.unpack_from("<i", scratch, 116)[0]
                touched = True
        if not touched:
            return False
        t = self.clock.now()
        for s in self.servos:
            if s.axis is None:
                continue
            if s.dxl_id in new_goal:
                goals[s.axis.name] = s.goal_deg(new_goal[s.dxl_id])
            elif s.torque:
                goals[s.axis.name] = s.axis.units_to_deg(s.motion.goal)
            else:
                goals[s.axis.name] = s.physical_deg(t)
        return self.collision_check(goals)

    def _refuse_collision(self, servos: list[Servo]) -> None:
        t = self.clock.now()
        for s in servos:
            log.warning("servo %d: goal refused: arms would collide", s.dxl_id)
            s._raise_hw_error(HW_OVERLOAD, t)

    def _write_common(self, writes: list[tuple[Servo, int, bytes]]) -> list[int]:
        """Validate and apply writes (atomic for the collision check); returns the error of each write."""
        errs = [s.check_write(addr, data) for s, addr, data in writes]
        ok = [w for w, e in zip(writes, errs, strict=True) if e == 0]
        if ok and self._goal_collides(ok):
            self._refuse_collision([s for s, a, d in ok if a <= 116 and a + len(d) >= 120])
            return [c.ERR_DATA_RANGE if e == 0 else e for e in errs]
        for s, addr, data in ok:
            s.apply_write(addr, data)
        return errs

    def _write(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        if len(params) < 3:
            return None
        addr = params[0] | (params[1] << 8)
        data = params[2:]
        targets = self._targets(dxl_id)
        errs = self._write_common([(s, addr, data) for s in targets])
        if dxl_id == c.BROADCAST_ID:
            return []
        s = targets[0]
        if s["status_return_level"] < 2:
            return []
        # the status carries the ID the packet was addressed to (also when the write changed the ID)
        return [c.status_packet(dxl_id, s.status_error(errs[0]))]

    def _reg_write(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        if len(params) < 3:
            return None
        addr = params[0] | (params[1] << 8)
        data = bytes(params[2:])
        out = []
        for s in self._targets(dxl_id):
            err = s.check_write(addr, data)
            if err == 0:
                s.registered = (addr, data)
                s.table[69] = 1
            if dxl_id != c.BROADCAST_ID:
                out += self._reply(s, err)
        return out

    def _action(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        writes = []
        for s in self._targets(dxl_id):
            if s.registered is not None:
                writes.append((s, *s.registered))
                s.registered = None
                s.table[69] = 0
        self._write_common(writes)
        if dxl_id == c.BROADCAST_ID:
            return []
        s = self.servo(dxl_id)
        return self._reply(s, 0)

    def _reboot(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        out = []
        for s in self._targets(dxl_id):
            if dxl_id != c.BROADCAST_ID:
                out += self._reply(s, 0)  # the status goes out before the reboot
            s.reboot()
            log.info("servo %d: reboot", s.dxl_id)
        return out

    def _factory_reset(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        if len(params) != 1:
            return None
        out = []
        for s in self._targets(dxl_id):
            err = s.factory_reset(params[0])
            if dxl_id != c.BROADCAST_ID:
                out += self._reply(s, err)
        return out

    def _clear(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        if len(params) != 5:
            return None
        if params != bytes([0x01, 0x44, 0x58, 0x4C, 0x22]):
            return self._simple_error(dxl_id, c.ERR_DATA_RANGE)
        out = []
        for s in self._targets(dxl_id):
            ok = s["operating_mode"] == MODE_EXTENDED and not s.motion.moving(self.clock.now())
            err = 0 if ok else c.ERR_RESULT_FAIL
            if dxl_id != c.BROADCAST_ID:
                out += self._reply(s, err)
        return out

    def _sync_read(self, dxl_id: int, params: bytes, fast: bool = False) -> list[bytes] | None:
        if dxl_id != c.BROADCAST_ID:
            return self._simple_error(dxl_id, c.ERR_INSTRUCTION)
        if len(params) < 5:
            return None
        addr, length = struct.unpack_from("<HH", params)
        ids = list(params[4:])
        servos = [s for i in ids if (s := self.servo(i)) is not None]
        return self._multi_read([(s, addr, length) for s in servos], fast)

    def _bulk_read(self, dxl_id: int, params: bytes, fast: bool = False) -> list[bytes] | None:
        if dxl_id != c.BROADCAST_ID:
            return self._simple_error(dxl_id, c.ERR_INSTRUCTION)
        if len(params) < 5 or len(params) % 5:
            return None
        reads = []
        for k in range(0, len(params), 5):
            i, addr, length = struct.unpack_from("<BHH", params, k)
            s = self.servo(i)
            if s is not None:
                reads.append((s, addr, length))
        return self._multi_read(reads, fast)

    def _multi_read(self, reads: list[tuple[Servo, int, int]], fast: bool) -> list[bytes]:
        self._prepare_read(reads)
        if not fast:
            out = []
            for s, addr, length in reads:
                err, data = s.read(addr, length)
                out += self._reply(s, err, data, level=1)
            return out
        if not reads:
            return []
        # Fast Sync/Bulk Read: one packet, ID 0xFE: 55 | ERR ID DATA CRC | ERR ID DATA CRC ... (last CRC is the
        # packet CRC). Each intermediate CRC is the CRC of the packet so far, as the devices chain it.
        parts = []
        for s, addr, length in reads:
            err, data = s.read(addr, length)
            parts.append((s.status_error(err), s.dxl_id, data))
        total_len = 1 + sum(2 + len(d) + 2 for _, _, d in parts)
        pkt = bytearray(c.HEADER + bytes([c.BROADCAST_ID, total_len & 0xFF, total_len >> 8, c.INST_STATUS]))
        for err, i, data in parts:
            pkt += bytes([err, i]) + data
            crc = c.crc16(pkt)
            pkt += bytes([crc & 0xFF, crc >> 8])
        return [bytes(pkt)]

    def _sync_write(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        if dxl_id != c.BROADCAST_ID:
            return self._simple_error(dxl_id, c.ERR_INSTRUCTION)
        if len(params) < 4:
            return None
        addr, length = struct.unpack_from("<HH", params)
        rest = params[4:]
        if length < 1 or not rest or len(rest) % (length + 1):
            return None
        writes = []
        for k in range(0, len(rest), length + 1):
            s = self.servo(rest[k])
            if s is not None:
                writes.append((s, addr, bytes(rest[k + 1: k + 1 + length])))
        self._write_common(writes)
        return []

    def _bulk_write(self, dxl_id: int, params: bytes) -> list[bytes] | None:
        if dxl_id != c.BROADCAST_ID:
            return self._simple_error(dxl_id, c.ERR_INSTRUCTION)
        writes = []
        k = 0
        while k < len(params):
            if k + 5 > len(params):
                return None
            i, addr, length = struct.unpack_from("<BHH", params, k)
            if length < 1 or k + 5 + length > len(params):
                return None
            s = self.servo(i)
            if s is not None:
                writes.append((s, addr, bytes(params[k + 5: k + 5 + length])))
            k += 5 + length
        if not writes and not params:
            return None
        self._write_common(writes)
        return []

    _HANDLERS = {
        c.INST_PING: _ping,
        c.INST_READ: _read,
        c.INST_WRITE: _write,
        c.INST_REG_WRITE: _reg_write,
        c.INST_ACTION: _action,
        c.INST_FACTORY_RESET: _factory_reset,
        c.INST_REBOOT: _reboot,
        c.INST_CLEAR: _clear,
        c.INST_SYNC_READ: _sync_read,
        c.INST_SYNC_WRITE: _sync_write,
        c.INST_BULK_READ: _bulk_read,
        c.INST_BULK_WRITE: _bulk_write,
        c.INST_FAST_SYNC_READ: lambda self, i, p: self._sync_read(i, p, fast=True),
        c.INST_FAST_BULK_READ: lambda self, i, p: self._bulk_read(i, p, fast=True),
    }
