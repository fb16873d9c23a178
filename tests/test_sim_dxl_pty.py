"""The real dynamixel_sdk against `gonio-sim serve` through a pseudo-terminal."""

from __future__ import annotations

import time

import pytest
from dynamixel_sdk import (
    COMM_RX_TIMEOUT,
    COMM_SUCCESS,
    GroupBulkRead,
    GroupSyncRead,
    GroupSyncWrite,
    PacketHandler,
    PortHandler,
)

from simulator.devices import dxl_codec as c
from tests.helpers import UNITS_PER_DEG, units

LIGHT, DET = 1, 2


def le32(v: int) -> list[int]:
    return list(int(v).to_bytes(4, "little", signed=True))


@pytest.fixture(scope="module")
def server(serve_process, simulated_toml):
    sp = serve_process(simulated_toml)
    yield sp
    assert sp.stop() == 0


@pytest.fixture
def dxl(server):
    port = PortHandler(server.ports["dynamixel"])
    assert port.openPort()
    assert port.setBaudRate(1000000)
    ph = PacketHandler(2.0)
    yield port, ph
    # leave the servos in a known state for the next test
    for i in (LIGHT, DET):
        ph.reboot(port, i)
    port.closePort()


def test_ping_every_servo(dxl):
    port, ph = dxl
    for i in (LIGHT, DET):
        model, res, err = ph.ping(port, i)
        assert (model, res, err) == (1020, COMM_SUCCESS, 0)
    model, res, err = ph.ping(port, 7)
    assert res == COMM_RX_TIMEOUT


def test_read_write_control_table(dxl):
    port, ph = dxl
    val, res, err = ph.read1ByteTxRx(port, LIGHT, 7)
    assert (val, res, err) == (LIGHT, COMM_SUCCESS, 0)
    fw, res, _ = ph.read1ByteTxRx(port, LIGHT, 6)
    assert res == COMM_SUCCESS and fw > 0
    pos, res, err = ph.read4ByteTxRx(port, DET, 132)
    assert res == COMM_SUCCESS and pos == units(45.0)
    res, err = ph.write4ByteTxRx(port, LIGHT, 112, 123)
    assert (res, err) == (COMM_SUCCESS, 0)
    assert ph.read4ByteTxRx(port, LIGHT, 112) == (123, COMM_SUCCESS, 0)
    # read-only item
    res, err = ph.write4ByteTxRx(port, LIGHT, 132, 5)
    assert res == COMM_SUCCESS and err & 0x7F == c.ERR_ACCESS


def test_eeprom_locked_while_torque_on(dxl):
    port, ph = dxl
    assert ph.write1ByteTxRx(port, LIGHT, 11, 4) == (COMM_SUCCESS, 0)  # torque off: allowed
    assert ph.write1ByteTxRx(port, LIGHT, 11, 3) == (COMM_SUCCESS, 0)
    assert ph.write1ByteTxRx(port, LIGHT, 64, 1) == (COMM_SUCCESS, 0)
    res, err = ph.write1ByteTxRx(port, LIGHT, 11, 4)
    assert res == COMM_SUCCESS and err == c.ERR_ACCESS
    assert ph.read1ByteTxRx(port, LIGHT, 11)[0] == 3


def test_sync_write_sync_read_wait_for_goal(dxl):
    port, ph = dxl
    for i in (LIGHT, DET):
        assert ph.write4ByteTxRx(port, i, 108, 50) == (COMM_SUCCESS, 0)
        assert ph.write4ByteTxRx(port, i, 112, 200) == (COMM_SUCCESS, 0)
        assert ph.write1ByteTxRx(port, i, 64, 1) == (COMM_SUCCESS, 0)
    goals = {LIGHT: units(30.0), DET: units(-20.0)}
    sw = GroupSyncWrite(port, ph, 116, 4)
    for i, g in goals.items():
        assert sw.addParam(i, le32(g))
    assert sw.txPacket() == COMM_SUCCESS

    sr = GroupSyncRead(port, ph, 122, 14)  # Moving .. Present Position
    for i in goals:
        assert sr.addParam(i)
    deadline = time.monotonic() + 5.0
    while True:
        assert sr.txRxPacket() == COMM_SUCCESS
        moving = [sr.getData(i, 122, 1) for i in goals]
        if not any(moving):
            break
        assert time.monotonic() < deadline
    for i, g in goals.items():
        assert sr.isAvailable(i, 132, 4)
        assert sr.getData(i, 132, 4) == g
        assert ph.read1ByteTxRx(port, i, 123)[0] & 1  # Moving Status: in position
    # bulk read of different items from both servos
    br = GroupBulkRead(port, ph)
    assert br.addParam(LIGHT, 132, 4) and br.addParam(DET, 116, 4)
    assert br.txRxPacket() == COMM_SUCCESS
    assert br.getData(LIGHT, 132, 4) == goals[LIGHT]
    assert br.getData(DET, 116, 4) == goals[DET]


def test_collision_refused_with_alert(dxl):
    port, ph = dxl
    for i in (LIGHT, DET):
        assert ph.write1ByteTxRx(port, i, 64, 1) == (COMM_SUCCESS, 0)
    light_deg = (ph.read4ByteTxRx(port, LIGHT, 132)[0] - 2048) / UNITS_PER_DEG
    det_goal = ph.read4ByteTxRx(port, DET, 116)[0]
    # detector goal 3 deg from the retro direction (-theta_i): closer than min_separation = 6
    res, err = ph.write4ByteTxRx(port, DET, 116, units(-light_deg + 3.0))
    assert res == COMM_SUCCESS
    assert err & 0x80 and err & 0x7F == c.ERR_DATA_RANGE
    assert ph.read4ByteTxRx(port, DET, 116)[0] == det_goal  # goal unchanged
    hw, res, err = ph.read1ByteTxRx(port, DET, 70)
    assert res == COMM_SUCCESS and hw & 0x20 and err & 0x80
    assert ph.read1ByteTxRx(port, DET, 64)[0] == 0  # torque off per Shutdown
    # reboot clears the latched error
    assert ph.reboot(port, DET)[0] == COMM_SUCCESS  # status (with alert) goes out before the reboot
    assert ph.read1ByteTxRx(port, DET, 70) == (0, COMM_SUCCESS, 0)
    # a legal goal is accepted
    assert ph.write1ByteTxRx(port, DET, 64, 1) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, DET, 116, units(-light_deg + 10.0)) == (COMM_SUCCESS, 0)


def test_corrupted_packet_gets_crc_error_status(dxl):
    port, ph = dxl
    pkt = bytearray(c.instruction_packet(LIGHT, c.INST_READ, [132, 0, 4, 0]))
    pkt[-1] ^= 0x5A
    port.clearPort()
    port.writePort(bytes(pkt))
    port.setPacketTimeout(30)
    rx, res = ph.rxPacket(port, False)
    assert res == COMM_SUCCESS
    assert rx[4] == LIGHT and rx[8] & 0x7F == c.ERR_CRC
    # the device stays responsive
    assert ph.ping(port, LIGHT)[1] == COMM_SUCCESS


def test_stuffed_packet_accepted(dxl):
    port, ph = dxl
    # Goal PWM = -1 and Goal Current = 253 in one write: the data bytes are FF FF FD 00
    value = int.from_bytes(bytes([0xFF, 0xFF, 0xFD, 0x00]), "little", signed=True)
    data = [100, 0] + le32(value)
    pkt = c.instruction_packet(LIGHT, c.INST_WRITE, data)
    assert b"\xff\xff\xfd\xfd" in pkt  # stuffed on the wire
    port.clearPort()
    port.writePort(pkt)
    port.setPacketTimeout(30)
    rx, res = ph.rxPacket(port, False)
    assert res == COMM_SUCCESS and rx[8] == 0
    assert ph.read4ByteTxRx(port, LIGHT, 100) == (value, COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, LIGHT, 100, 0) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, LIGHT, 100, value) == (COMM_SUCCESS, 0)  # the SDK sends this unstuffed
    assert ph.read4ByteTxRx(port, LIGHT, 100) == (value, COMM_SUCCESS, 0)
