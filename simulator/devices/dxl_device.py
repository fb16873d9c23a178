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

from simulator.devices import dxl_codec as c
from simulator.devices.dxl_servo import (
    DYNAMIC_START,
    HW_OVERLOAD,
    MODE_EXTENDED,
    CollisionCheck,
    Servo,
)
from simulator.world.clock import SimClock
from simulator.world.faults import FaultInjector

log = logging.getLogger("simulator.dxl")


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
