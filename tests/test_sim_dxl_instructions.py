"""Less common Protocol 2.0 instructions and error statuses, through the real SDK in-process (sim:// URL)."""

from __future__ import annotations

import pytest
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupBulkWrite,
    GroupSyncRead,
    PacketHandler,
)
from hypothesis import given, settings
from hypothesis import strategies as st

from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from simulator.devices import dxl_codec as c
from simulator.ports.sdk_port import SimPortHandler
from simulator.ports.transports import register_bench, unregister_bench


@pytest.fixture
def dxl(base_config_dict):
    bench = VirtualBench(config_from_dict(base_config_dict))
    name = f"instr-{id(bench)}"
    register_bench(name, bench)
    port = SimPortHandler(f"sim://{name}/dynamixel")
    assert port.openPort()
    yield bench, port, PacketHandler(2.0)
    port.closePort()
    unregister_bench(name)


def test_broadcast_ping(dxl):
    bench, port, ph = dxl
    data, res = ph.broadcastPing(port)
    assert res == COMM_SUCCESS
    assert data == {1: [1020, 48], 2: [1020, 48]}


def test_model_from_config(config_dict):
    b = VirtualBench(config_from_dict(config_dict({"axes": {"detector": {"model": "XL430-W250"}}})))
    out = b.process("dynamixel", c.instruction_packet(2, c.INST_PING))
    assert c.split_status_stream(out) == [(2, 0, bytes([0x24, 0x04, 48]))]  # 1060


def test_stage_axis_adds_a_servo(config_dict):
    b = VirtualBench(config_from_dict(config_dict({"axes": {"stage": {
        "id": 3, "model": "XL430-W250", "units_per_deg": 4096 / 360, "zero_offset": 2048, "direction": 1,
        "min_deg": -180.0, "max_deg": 180.0, "park_deg": 0.0}}})))
    assert sorted(s.dxl_id for s in b.bus.servos) == [1, 2, 3]


def test_reg_write_action(dxl):
    bench, port, ph = dxl
    assert ph.write1ByteTxRx(port, 1, 64, 1) == (COMM_SUCCESS, 0)
    goal = 2048 + 200
    assert ph.regWriteTxRx(port, 1, 116, 4, list(goal.to_bytes(4, "little"))) == (COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 1, 69)[0] == 1
    assert ph.read4ByteTxRx(port, 1, 116)[0] == 2048
    assert ph.action(port, 1) == COMM_SUCCESS
    assert ph.read4ByteTxRx(port, 1, 132)[0] == goal


def test_bulk_write_and_fast_reads(dxl):
    bench, port, ph = dxl
    bw = GroupBulkWrite(port, ph)
    assert bw.addParam(1, 65, 1, [1]) and bw.addParam(2, 112, 4, [100, 0, 0, 0])
    assert bw.txPacket() == COMM_SUCCESS
    assert ph.read1ByteTxRx(port, 1, 65)[0] == 1 and ph.read4ByteTxRx(port, 2, 112)[0] == 100
    sr = GroupSyncRead(port, ph, 132, 4)
    sr.addParam(1)
    sr.addParam(2)
    assert sr.fastSyncRead() == COMM_SUCCESS
    assert sr.getData(1, 132, 4) == 2048 and sr.getData(2, 132, 4) == 2560
    br = GroupBulkRead(port, ph)
    br.addParam(1, 65, 1)
    br.addParam(2, 132, 4)
    assert br.fastBulkRead() == COMM_SUCCESS
    assert br.getData(1, 65, 1) == 1 and br.getData(2, 132, 4) == 2560


def test_error_statuses(dxl):
    bench, port, ph = dxl
    # goal outside the position limits (position mode): Data Limit
    assert ph.write1ByteTxRx(port, 2, 64, 1) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, 2, 116, 5000) == (COMM_SUCCESS, c.ERR_DATA_LIMIT)
    # out-of-range value: Data Range
    assert ph.write1ByteTxRx(port, 2, 65, 7) == (COMM_SUCCESS, c.ERR_DATA_RANGE)
    # read past the table: Access Error
    assert ph.read4ByteTxRx(port, 2, 146)[1:] == (COMM_SUCCESS, c.ERR_ACCESS)
    # unknown instruction: Instruction Error
    out = bench.process("dynamixel", c.instruction_packet(1, 0x77))
    assert c.split_status_stream(out) == [(1, c.ERR_INSTRUCTION, b"")]
    # malformed read (3 parameters): Data Length
    out = bench.process("dynamixel", c.instruction_packet(1, c.INST_READ, [132, 0, 4]))
    assert c.split_status_stream(out) == [(1, c.ERR_DATA_LENGTH, b"")]
    # factory reset refused with torque on, accepted with torque off (ID kept with option 0x02)
    assert ph.factoryReset(port, 2, 0x02)[1] == c.ERR_ACCESS
    assert ph.write1ByteTxRx(port, 2, 64, 0) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, 2, 9, 0) == (COMM_SUCCESS, 0)
    assert ph.factoryReset(port, 2, 0x02) == (COMM_SUCCESS, 0)
    assert ph.read1ByteTxRx(port, 2, 9) == (250, COMM_SUCCESS, 0)


def test_status_return_level(dxl):
    bench, port, ph = dxl
    ph.write1ByteTxRx(port, 1, 68, 1)  # already answered (or not) under the new level
    assert ph.write1ByteTxRx(port, 1, 65, 1)[0] == COMM_RX_TIMEOUT  # writes no longer answered
    assert ph.read1ByteTxRx(port, 1, 65) == (1, COMM_SUCCESS, 0)   # reads still are
    assert ph.ping(port, 1)[1] == COMM_SUCCESS


def test_id_change(dxl):
    bench, port, ph = dxl
    assert ph.write1ByteTxRx(port, 2, 7, 9) == (COMM_SUCCESS, 0)
    assert ph.ping(port, 9)[1] == COMM_SUCCESS and ph.ping(port, 2)[1] == COMM_RX_TIMEOUT


@settings(max_examples=60, deadline=None)
@given(pwm=st.integers(-885, 885), cur=st.integers(-1193, 1193), stuffed=st.booleans())
def test_stuffed_and_unstuffed_writes_roundtrip(base_config_dict, pwm, cur, stuffed):
    bench = VirtualBench(config_from_dict(base_config_dict))
    data = pwm.to_bytes(2, "little", signed=True) + cur.to_bytes(2, "little", signed=True)
    params = bytes([100, 0]) + data
    if stuffed:
        pkt = c.instruction_packet(1, c.INST_WRITE, params)
    else:  # as the Python SDK sends it: no stuffing, LEN/CRC over the raw bytes
        body = bytes([c.INST_WRITE]) + params
        head = c.HEADER + bytes([1, len(body) + 2, 0])
        crc = c.crc16(head + body)
        pkt = head + body + bytes([crc & 0xFF, crc >> 8])
    assert c.split_status_stream(bench.process("dynamixel", pkt)) == [(1, 0, b"")]
    out = bench.process("dynamixel", c.instruction_packet(1, c.INST_READ, [100, 0, 4, 0]))
    assert c.split_status_stream(out) == [(1, 0, data)]
