"""Protocol 2.0 codec: CRC test vectors of the reference, stuffing, framing."""

from __future__ import annotations

from dynamixel_sdk import PacketHandler

from simulator.devices import dxl_codec as c

PING_1 = bytes.fromhex("FF FF FD 00 01 03 00 01 19 4E")
PING_1_STATUS = bytes.fromhex("FF FF FD 00 01 07 00 55 00 06 04 26 65 5D")
READ_PP_1 = bytes.fromhex("FF FF FD 00 01 07 00 02 84 00 04 00 1D 15")


def test_crc_vectors():
    assert c.crc16(PING_1[:-2]) == 0x4E19
    assert c.crc16(PING_1_STATUS[:-2]) == 0x5D65
    assert c.crc16(READ_PP_1[:-2]) == 0x151D


def test_crc_matches_sdk_table():
    ph = PacketHandler(2.0)
    data = bytes(range(256)) * 3
    assert c.crc16(data) == ph.updateCRC(0, list(data), len(data))


def test_build_packets_match_vectors():
    assert c.instruction_packet(1, c.INST_PING) == PING_1
    assert c.status_packet(1, 0, bytes([0x06, 0x04, 0x26])) == PING_1_STATUS
    assert c.instruction_packet(1, c.INST_READ, [0x84, 0x00, 0x04, 0x00]) == READ_PP_1


def test_stuffing_roundtrip():
    payload = bytes([0x03, 0xFF, 0xFF, 0xFD, 0x00, 0xFF, 0xFF, 0xFD])
    st = c.stuff(payload)
    assert st == bytes([0x03, 0xFF, 0xFF, 0xFD, 0xFD, 0x00, 0xFF, 0xFF, 0xFD, 0xFD])
    assert c.unstuff(st) == payload
    pkt = c.build_packet(5, payload)
    assert pkt[5] | (pkt[6] << 8) == len(st) + 2  # LEN counts stuffed bytes
    (fr,) = c.PacketParser().feed(pkt)
    assert fr.crc_ok and fr.params_candidates()[0] == payload[1:]


def test_parser_skips_junk_and_splits_chunks():
    p = c.PacketParser()
    stream = b"\x00\x12\xff" + PING_1 + b"\xff\xff" + READ_PP_1
    frames = []
    for i in range(len(stream)):
        frames += p.feed(stream[i:i + 1])
    assert [f.raw for f in frames] == [PING_1, READ_PP_1]
    assert all(f.crc_ok for f in frames)
    bad = bytearray(PING_1)
    bad[-2] ^= 1
    (fr,) = p.feed(bytes(bad))
    assert not fr.crc_ok


def test_split_status_stream():
    data = PING_1_STATUS + b"junk" + c.status_packet(2, 0x80, b"\x01")
    assert c.split_status_stream(data) == [(1, 0, bytes([6, 4, 0x26])), (2, 0x80, b"\x01")]
