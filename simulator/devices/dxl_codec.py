"""Dynamixel Protocol 2.0 packet codec: CRC-16, byte stuffing and an incremental framing parser.

Pure functions plus one small stateful class (:class:`PacketParser`); no I/O, no device logic.

Packet layout (see ``shared/reference/dynamixel-protocol2.md``)::

    instruction: FF FF FD 00 | ID | LEN_L LEN_H | INST | params... | CRC_L CRC_H
    status:      FF FF FD 00 | ID | LEN_L LEN_H | 0x55 | ERR | params... | CRC_L CRC_H

LEN counts the bytes after LEN (instruction, parameters and the two CRC bytes) as transmitted, i.e. after
stuffing. The CRC (CRC-16/BUYPASS: poly 0x8005, init 0, not reflected) covers every transmitted byte before it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
MAX_ID = 0xFC

INST_PING = 0x01
INST_READ = 0x02
INST_WRITE = 0x03
INST_REG_WRITE = 0x04
INST_ACTION = 0x05
INST_FACTORY_RESET = 0x06
INST_REBOOT = 0x08
INST_CLEAR = 0x10
INST_STATUS = 0x55
INST_SYNC_READ = 0x82
INST_SYNC_WRITE = 0x83
INST_FAST_SYNC_READ = 0x8A
INST_BULK_READ = 0x92
INST_BULK_WRITE = 0x93
INST_FAST_BULK_READ = 0x9A

ERR_NONE = 0
ERR_RESULT_FAIL = 1
ERR_INSTRUCTION = 2
ERR_CRC = 3
ERR_DATA_RANGE = 4
ERR_DATA_LENGTH = 5
ERR_DATA_LIMIT = 6
ERR_ACCESS = 7
ERRBIT_ALERT = 0x80

#: Largest LEN the parser accepts; longer frames are treated as garbage (the SDK's buffers are 1 KiB).
MAX_LEN = 1024


def _make_crc_table() -> list[int]:
    table = []
    for i in range(256):
        crc = i << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
        table.append(crc & 0xFFFF)
    return table


_CRC_TABLE = _make_crc_table()


def crc16(data: bytes | bytearray | memoryview, crc: int = 0) -> int:
    """CRC-16/BUYPASS (poly 0x8005, init 0, no reflection) of ``data``, continuing from ``crc``."""
    table = _CRC_TABLE
    for b in data:
        crc = ((crc << 8) ^ table[((crc >> 8) ^ b) & 0xFF]) & 0xFFFF
    return crc


def stuff(payload: bytes) -> bytes:
    """Byte-stuff an instruction/status + parameter area: every ``FF FF FD`` becomes ``FF FF FD FD``."""
    if b"\xff\xff\xfd" not in payload:
        return bytes(payload)
    out = bytearray()
    for b in payload:
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF:
            out.append(0xFD)
    return bytes(out)


def unstuff(payload: bytes) -> bytes:
    """Undo :func:`stuff`: every ``FF FF FD FD`` becomes ``FF FF FD``."""
    if b"\xff\xff\xfd\xfd" not in payload:
        return bytes(payload)
    out = bytearray()
    i = 0
    n = len(payload)
    while i < n:
        b = payload[i]
        out.append(b)
        if b == 0xFD and len(out) >= 3 and out[-3] == 0xFF and out[-2] == 0xFF and i + 1 < n and payload[i + 1] == 0xFD:
            i += 1  # drop the stuffing byte
        i += 1
    return bytes(out)


def build_packet(dxl_id: int, body: bytes) -> bytes:
    """Frame ``body`` (instruction byte + parameters, unstuffed) for ``dxl_id``: stuff, add LEN and CRC."""
    stuffed = stuff(bytes(body))
    length = len(stuffed) + 2
    head = HEADER + bytes([dxl_id & 0xFF, length & 0xFF, (length >> 8) & 0xFF])
    pkt = head + stuffed
    crc = crc16(pkt)
    return pkt + bytes([crc & 0xFF, crc >> 8])


def instruction_packet(dxl_id: int, inst: int, params: bytes | list[int] = b"") -> bytes:
    """An instruction packet (stuffed, with CRC)."""
    return build_packet(dxl_id, bytes([inst]) + bytes(params))


def status_packet(dxl_id: int, error: int, params: bytes | list[int] = b"") -> bytes:
    """A status packet (stuffed, with CRC) as a device sends it."""
    return build_packet(dxl_id, bytes([INST_STATUS, error & 0xFF]) + bytes(params))


@dataclass
class Frame:
    """One framed packet as received.

    ``raw`` is the whole packet as transmitted; ``body`` is the bytes between LEN and CRC as transmitted (possibly
    stuffed); ``crc_ok`` tells whether the CRC matched.
    """

    dxl_id: int
    body: bytes
    raw: bytes
    crc_ok: bool

    @property
    def instruction(self) -> int:
        return self.body[0] if self.body else -1

    def params_candidates(self) -> list[bytes]:
        """Possible parameter areas: unstuffed first; the raw area too when it differs.

        A conforming sender stuffs, but the Python SDK sends its packets unstuffed (its ``addStuffing`` result is
        discarded when the length changes), so both readings must be tried. A raw area containing ``FF FF FD`` not
        followed by ``FD`` can only be unstuffed and is returned alone.
        """
        area = self.body[1:]
        i = area.find(b"\xff\xff\xfd")
        definitely_raw = False
        while i >= 0:
            if i + 3 >= len(area) or area[i + 3] != 0xFD:
                definitely_raw = True
                break
            i = area.find(b"\xff\xff\xfd", i + 4)
        if definitely_raw:
            return [bytes(area)]
        un = unstuff(area)
        return [un] if un == area else [un, bytes(area)]


@dataclass
class PacketParser:
    """Incremental framing parser for a byte stream of Protocol 2.0 packets.

    Feed arbitrary chunks with :meth:`feed`; it returns every complete frame found (CRC good or bad). Junk before a
    header is skipped; an impossible LEN (< 3 or > :data:`MAX_LEN`) drops the header byte and resynchronises.
    ``max_buffer`` bounds memory when garbage without headers keeps coming.
    """

    max_buffer: int = 4 * MAX_LEN
    _buf: bytearray = field(default_factory=bytearray)

    def reset(self) -> None:
        self._buf.clear()

    @property
    def pending(self) -> int:
        """Bytes buffered but not yet framed."""
        return len(self._buf)

    def feed(self, data: bytes) -> list[Frame]:
        buf = self._buf
        buf.extend(data)
        frames: list[Frame] = []
        while True:
            start = buf.find(HEADER)
            if start < 0:
                # keep a possible partial header at the end
                keep = 0
                for k in (3, 2, 1):
                    if len(buf) >= k and buf[-k:] == HEADER[:k]:
                        keep = k
                        break
                del buf[: len(buf) - keep]
                break
            if start:
                del buf[:start]
            if len(buf) < 7:
                break
            length = buf[5] | (buf[6] << 8)
            if length < 3 or length > MAX_LEN:
                del buf[:1]
                continue
            total = 7 + length
            if len(buf) < total:
                if len(buf) > self.max_buffer:
                    del buf[:1]
                    continue
                break
            raw = bytes(buf[:total])
            del buf[:total]
            crc_rx = raw[-2] | (raw[-1] << 8)
            frames.append(Frame(dxl_id=raw[4], body=raw[7:-2], raw=raw, crc_ok=crc16(raw[:-2]) == crc_rx))
        return frames


def parse_status(raw: bytes) -> tuple[int, int, bytes]:
    """Decode one complete status packet -> (id, error, params). Raises ValueError if malformed or CRC is bad."""
    if len(raw) < 11 or raw[:4] != HEADER:
        raise ValueError("not a status packet")
    length = raw[5] | (raw[6] << 8)
    if len(raw) != 7 + length:
        raise ValueError("length mismatch")
    if crc16(raw[:-2]) != (raw[-2] | (raw[-1] << 8)):
        raise ValueError("bad CRC")
    body = unstuff(raw[7:-2])
    if body[0] != INST_STATUS:
        raise ValueError("not a status packet")
    return raw[4], body[1], body[2:]


def split_status_stream(data: bytes) -> list[tuple[int, int, bytes]]:
    """Decode all status packets with a good CRC in ``data`` -> list of (id, error, params)."""
    out = []
    for fr in PacketParser().feed(data):
        if fr.crc_ok and fr.body[:1] == bytes([INST_STATUS]):
            body = unstuff(fr.body)
            if len(body) >= 2:
                out.append((fr.dxl_id, body[1], body[2:]))
    return out
