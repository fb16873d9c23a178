"""The detector firmware built with the 16-bit ADC option (``make ADC=ads1115``): the ADS1115 on I2C, which the
emulation harness answers register by register as its datasheet gives them (simulator/devices/avr_harness.c).

Skipped, with the reason, without avr-gcc and simavr (scripts/system-packages.sh installs them)."""

from __future__ import annotations

import pytest

from simulator.devices import firmware as fw
from tests.test_firmware import Port, read_values

PROBLEM = fw.toolchain_problem()
pytestmark = pytest.mark.skipif(PROBLEM is not None, reason=f"firmware tests skipped: {PROBLEM}")

LSB_MV = 4096.0 / 32768  # PGA +-4.096 V: 125 uV a code
NCONV = 5  # 0.01 s of conversions every 2 ms


@pytest.fixture(scope="module")
def board(tmp_path_factory):
    d = tmp_path_factory.mktemp("firmware")
    try:
        elf, harness = fw.build_firmware(d / "fw", adc="ads1115"), fw.build_harness(d)
    except fw.FirmwareError as e:
        pytest.skip(f"firmware tests skipped: {e}")
    with fw.EmulatedBoard(elf, harness) as b:
        port = Port(b.port)
        b.reset()
        assert "BOOT" in port.line()
        yield b, port
        port.close()


def test_reads_a_differential_voltage_to_the_lsb(board):
    b, port = board
    d = port.fields("DETECTOR?")
    assert d["bits"] == "16" and d["conversions"] == str(NCONV) and d["t_int"] == "0.01"
    assert int(d["saturation"]) == 32767 * NCONV
    for out_mv, ref_mv in ((1234.5, 100.0), (2500.0, 30.0), (30.0, 30.0), (30.0, 1000.0), (4000.0, 0.0)):
        b.send(f"AIN1 {ref_mv}")
        b.set_adc(out_mv)
        f, vals = read_values(port, "READ 3")
        code = round((out_mv - ref_mv) / LSB_MV)  # AIN0 - AIN1 in codes of 125 uV
        assert vals == [code * NCONV] * 3, (out_mv, ref_mv, vals)
        assert f["sat"] == "0"
    b.send("AIN1 0")
    b.set_adc(1000.0 + 0.4 * LSB_MV)  # within half an LSB: the same code
    assert read_values(port, "READ 1")[1] == [8000 * NCONV]
    b.set_adc(1000.0 + 1.0 * LSB_MV)  # one LSB more: one code more
    assert read_values(port, "READ 1")[1] == [8001 * NCONV]
    b.set_adc(4500.0)  # beyond +4.096 V: the largest code, counted as clipped
    f, vals = read_values(port, "READ 2")
    assert vals == [32767 * NCONV] * 2 and f["sat"] == "2"


def test_integration_time_in_whole_conversions(board):
    b, port = board
    b.set_adc(500.0)
    try:
        assert port.cmd("INT 0.1") == ["ok"]
        f, vals = read_values(port, "READ 1")
        assert f["t_int"] == "0.1" and vals == [4000 * 50]
        t0 = float(port.fields("TIME?")["t"])
        port.fields("READ 4")
        assert 0.4 <= float(port.fields("TIME?")["t"]) - t0 < 0.45  # one conversion every 2 ms
    finally:
        port.cmd("INT 0.01")


def test_a_missing_ads1115_is_a_named_error(board):
    b, port = board
    b.send("ADS1115 0")  # the device never acknowledges its address (unwired, wrong ADDR, dead)
    try:
        assert port.cmd("READ 2") == ["error:12"]
        assert port.cmd("DARK") == ["error:12"]
        assert port.fields("ID?")["name"] == "gonio-detector"  # the board itself still answers
    finally:
        b.send("ADS1115 1")
    b.set_adc(1000.0)
    assert read_values(port, "READ 1")[1] == [8000 * NCONV]
