"""Fault injection: dropped replies, corrupted bytes, overload, stall, saturation, vanishing ports."""

from __future__ import annotations

import time

import pytest
import serial
from dynamixel_sdk import COMM_RX_CORRUPT, COMM_RX_TIMEOUT, COMM_SUCCESS, PacketHandler, PortHandler

import simulator  # noqa: F401 - registers sim://
from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from simulator.devices import dxl_codec as c
from simulator.ports.sdk_port import SimPortHandler
from simulator.ports.transports import PtyServer, register_bench, unregister_bench
from tests.helpers import units


@pytest.fixture
def sim_dxl(config_dict):
    """``sim_dxl(faults)`` -> (bench, port, packet handler) in-process through the sim:// URL handler."""
    made = []

    def make(faults: dict, **sim):
        bench = VirtualBench(config_from_dict(config_dict({"simulator": {"faults": faults, **sim}})))
        name = f"faults-{id(bench)}"
        register_bench(name, bench)
        port = SimPortHandler(f"sim://{name}/dynamixel")
        assert port.openPort()
        made.append((name, port))
        return bench, port, PacketHandler(2.0)

    yield make
    for name, port in made:
        port.closePort()
        unregister_bench(name)


def test_dropped_reply_times_out_then_next_works(sim_dxl):
    bench, port, ph = sim_dxl({"drop_reply_rate": 0.5})
    results = [ph.ping(port, 1)[1] for _ in range(40)]
    assert COMM_RX_TIMEOUT in results and COMM_SUCCESS in results
    assert set(results) == {COMM_SUCCESS, COMM_RX_TIMEOUT}  # a timeout never breaks the next transaction
    assert bench.dxl_comm_faults.counts["dropped"] == results.count(COMM_RX_TIMEOUT)
    assert 8 <= results.count(COMM_RX_TIMEOUT) <= 32
    # the drop pattern is deterministic for the seed
    bench2, port2, _ = sim_dxl({"drop_reply_rate": 0.5})
    assert [ph.ping(port2, 1)[1] for _ in range(40)] == results


def test_corrupted_bytes_give_rx_corrupt(sim_dxl):
    bench, port, ph = sim_dxl({"corrupt_byte_rate": 0.05})
    results = [ph.read4ByteTxRx(port, 2, 132) for _ in range(60)]
    codes = {r[1] for r in results}
    assert COMM_RX_CORRUPT in codes or COMM_RX_TIMEOUT in codes
    good = [r for r in results if r[1] == COMM_SUCCESS]
    assert good and all(v == units(45.0) for v, _, _ in good)
    assert bench.dxl_comm_faults.counts["corrupted"] > 0


def test_no_faults_configured_means_no_faults(sim_dxl):
    bench, port, ph = sim_dxl({})
    assert all(ph.ping(port, 1)[1] == COMM_SUCCESS for _ in range(50))


def enable_and_move(port, ph, dxl_id: int, deg: float) -> None:
    assert ph.write1ByteTxRx(port, dxl_id, 64, 1) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, dxl_id, 112, 200) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, dxl_id, 108, 50) == (COMM_SUCCESS, 0)
    assert ph.write4ByteTxRx(port, dxl_id, 116, units(deg)) == (COMM_SUCCESS, 0)


def test_overload_sets_alert_and_torque_off(sim_dxl):
    bench, port, ph = sim_dxl({"overload_rate": 1.0})
    enable_and_move(port, ph, 2, -30.0)
    moving, res, err = ph.read1ByteTxRx(port, 2, 122)  # fast time: the fault fires by now
    assert res == COMM_SUCCESS and moving == 0 and err & 0x80
    hw = ph.read1ByteTxRx(port, 2, 70)[0]
    assert hw & 0x20
    assert ph.read1ByteTxRx(port, 2, 64)[0] == 0
    pos = ph.read4ByteTxRx(port, 2, 132)[0]
    assert units(-30.0) < pos < units(45.0)  # stopped partway
    ph.reboot(port, 2)
    assert ph.read1ByteTxRx(port, 2, 70) == (0, COMM_SUCCESS, 0)


def test_overload_respects_shutdown(sim_dxl):
    bench, port, ph = sim_dxl({"overload_rate": 1.0})
    assert ph.write1ByteTxRx(port, 2, 63, 0) == (COMM_SUCCESS, 0)  # Shutdown: nothing switches torque off
    enable_and_move(port, ph, 2, -30.0)
    for _ in range(3):
        ph.read1ByteTxRx(port, 2, 122)
    assert ph.read1ByteTxRx(port, 2, 70)[0] & 0x20
    assert ph.read1ByteTxRx(port, 2, 64)[0] == 1
    assert ph.read4ByteTxRx(port, 2, 132)[0] == units(-30.0)


def test_stall_keeps_moving_then_overloads(sim_dxl):
    bench, port, ph = sim_dxl({"stall_rate": 1.0, "stall_overload_s": 2.0})
    t0 = bench.clock.now()
    enable_and_move(port, ph, 1, 40.0)
    servo = bench.bus.servo(1)
    t_stall = servo.motion.stall_time
    assert t0 < t_stall < t0 + servo.motion.profile.duration
    bench.clock.jump_to(t_stall + 1.0)  # stalled for 1 s: still "moving", no error yet
    assert ph.read1ByteTxRx(port, 1, 70) == (0, COMM_SUCCESS, 0)
    p1 = ph.read4ByteTxRx(port, 1, 132)[0]  # a motion read completes pending events in fast time
    assert units(0.0) < p1 < units(40.0)
    assert ph.read1ByteTxRx(port, 1, 70)[0] & 0x20  # the blocked servo overloads ...
    assert bench.clock.now() == pytest.approx(t_stall + 2.0)  # ... after stall_overload_s
    assert ph.read1ByteTxRx(port, 1, 64)[0] == 0
    assert ph.read4ByteTxRx(port, 1, 132)[0] == p1


def test_stepper_stall_alarm(config_dict):
    b = VirtualBench(config_from_dict(config_dict({"bench": {"motion": "serial"},
                                                   "simulator": {"faults": {"stall_rate": 1.0}}})))
    assert b.process("serial", f"MOVE L{units(40)}\n".encode()) == b"ok\n"
    st = b.process("serial", b"STATUS?\n").decode()
    assert "state=Alarm" in st and "alarm=21" in st
    lpos = int(st.split("L=")[1].split()[0])
    assert units(0) < lpos < units(40)
    assert b.process("serial", f"MOVE L{units(10)}\n".encode()) == b"error:9\n"
    assert b.process("serial", b"RESET\n") == b"ok\n"
    assert "state=Idle" in b.process("serial", b"STATUS?\n").decode()


def test_saturation_fault(config_dict):
    b = VirtualBench(config_from_dict(config_dict({"simulator": {"faults": {"saturate_rate": 0.5}}})))
    line = b.process("serial", b"READ 40\n").decode().splitlines()[0]
    f = dict(x.split("=", 1) for x in line.split()[1:])
    vals = [int(v) for v in f["values"].split(",")]
    n_sat = vals.count(65535)
    assert int(f["sat"]) == n_sat and 5 <= n_sat <= 35
    assert b.detector_faults.counts["saturate"] == n_sat


def test_serial_comm_faults_opt_in(config_dict):
    b = VirtualBench(config_from_dict(config_dict({"simulator": {"faults": {"drop_reply_rate": 1.0}}})))
    assert b.process("serial", b"TIME?\n").endswith(b"ok\n")  # serial_comm_faults = false: unaffected
    b = VirtualBench(config_from_dict(config_dict({"simulator": {"faults": {"drop_reply_rate": 1.0,
                                                                           "serial_comm_faults": True}}})))
    assert b.process("serial", b"TIME?\n") == b""


def test_port_vanishes_in_process(config_dict):
    b = VirtualBench(config_from_dict(config_dict({"simulator": {"faults": {"port_vanish_after_s": 1.0}}})))
    register_bench("vanish-url", b)
    try:
        s = serial.serial_for_url("sim://vanish-url/serial", timeout=0.5)
        s.write(b"DWELL 0.5\n")
        assert s.readline() == b"ok\n"
        s.write(b"DWELL 0.6\n")  # simulated time passes 1 s: the port is gone
        with pytest.raises(serial.SerialException):
            s.readline()
        with pytest.raises(serial.SerialException):
            s.write(b"TIME?\n")
    finally:
        unregister_bench("vanish-url")


def test_port_vanishes_on_pty(config_dict):
    b = VirtualBench(config_from_dict(config_dict({"simulator": {"faults": {"port_vanish_after_s": 1.0,
                                                                           "vanish_ports": "all"}}})))
    with PtyServer(b) as server:
        paths = server.paths()
        port = PortHandler(paths["dynamixel"])
        assert port.openPort()
        ph = PacketHandler(2.0)
        assert ph.ping(port, 1)[1] == COMM_SUCCESS
        ser = serial.Serial(paths["serial"], 115200, timeout=1)
        ser.write(b"DWELL 0.5\n")
        assert ser.readline() == b"ok\n"
        ser.write(b"DWELL 0.6\n")  # simulated time passes 1 s: both ports vanish
        deadline = time.monotonic() + 3
        with pytest.raises((serial.SerialException, OSError)):
            while time.monotonic() < deadline:
                ser.write(b"TIME?\n")
                ser.readline()
                time.sleep(0.05)
        ser.close()
        with pytest.raises((serial.SerialException, OSError)):
            while time.monotonic() < deadline:
                ph.ping(port, 1)
                time.sleep(0.05)
        port.is_using = False
        port.closePort()


def test_crc_error_status_in_process(sim_dxl):
    bench, port, ph = sim_dxl({})
    pkt = bytearray(c.instruction_packet(2, c.INST_PING))
    pkt[-2] ^= 0xFF
    out = bench.process("dynamixel", bytes(pkt))
    assert c.split_status_stream(out) == [(2, c.ERR_CRC, b"")]
    # broadcast with a bad CRC: no reply at all
    pkt = bytearray(c.instruction_packet(c.BROADCAST_ID, c.INST_PING))
    pkt[-1] ^= 1
    assert bench.process("dynamixel", bytes(pkt)) == b""


@pytest.mark.parametrize("faults, expected", [
    ({"drop_reply_rate": 0.5}, {COMM_RX_TIMEOUT}),
    ({"corrupt_byte_rate": 0.05}, {COMM_RX_CORRUPT, COMM_RX_TIMEOUT}),  # a timeout if the header broke
])
def test_comm_faults_through_the_pty_then_the_next_transaction_works(config_dict, faults, expected, monkeypatch):
    """No failure is sticky: with the real SDK on the pty, the faults are switched on until a transaction fails,
    then off, and the very next transaction must succeed with the right value (stale bytes of a corrupted reply
    must not spoil it). The faults come from the simulator's seed: the same pattern every run.

    The SDK's reply deadline is wall-clock (about 34 ms); the simulator's pump thread shares this process, so on a
    loaded machine a reply can miss it without any fault. The deadline is widened to about 0.2 s so that only the
    injected faults fail transactions."""
    import dynamixel_sdk.port_handler

    monkeypatch.setattr(dynamixel_sdk.port_handler, "LATENCY_TIMER", 100)
    b = VirtualBench(config_from_dict(config_dict({"simulator": {"seed": 1, "faults": faults}})))
    fault_cfg = b.cfg.sim.faults

    def switch(on: bool) -> None:
        for k, v in faults.items():
            setattr(fault_cfg, k, v if on else 0.0)

    failures = []
    with PtyServer(b) as server:
        port = PortHandler(server.paths()["dynamixel"])
        assert port.openPort()
        ph = PacketHandler(2.0)
        try:
            for _ in range(8):
                switch(True)
                for _ in range(40):
                    value, res = ph.read4ByteTxRx(port, 2, 132)[:2]
                    if res != COMM_SUCCESS:
                        break
                    assert value == units(45.0)
                else:
                    raise AssertionError(f"no fault in 40 transactions with {faults}")
                failures.append(res)
                switch(False)
                assert ph.read4ByteTxRx(port, 2, 132)[:2] == (units(45.0), COMM_SUCCESS), failures
        finally:
            port.closePort()
    assert set(failures) <= expected, failures
    if "drop_reply_rate" in faults:
        assert b.dxl_comm_faults.counts["dropped"] == len(failures)  # every failure was one dropped reply
    else:
        assert COMM_RX_CORRUPT in failures and b.dxl_comm_faults.counts["corrupted"] >= len(failures)
