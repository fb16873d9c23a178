"""The detector board's firmware (firmware/detector), built with avr-gcc and run on an emulated ATmega328P
(simavr, simulator/devices/avr_harness.c compiled here), spoken to with pyserial and with acquisition's own driver.

Skipped, with the reason, where avr-gcc or simavr's headers are missing (Debian: gcc-avr avr-libc simavr
libsimavr-dev libsimavrparts1; scripts/system-packages.sh installs them when it can)."""

from __future__ import annotations

import time

import pytest

from simulator.devices import firmware as fw

PROBLEM = fw.toolchain_problem()
pytestmark = pytest.mark.skipif(PROBLEM is not None, reason=f"firmware tests skipped: {PROBLEM}")

T_INT = 0.01  # the firmware's power-up integration time: 80 conversions of 125 us
NCONV = 80


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("firmware")
    try:
        return fw.build_firmware(d / "fw"), fw.build_harness(d)
    except fw.FirmwareError as e:  # a partial toolchain: say what failed
        pytest.skip(f"firmware tests skipped: {e}")


class Port:
    """pyserial on the board's pty, one command at a time: data lines and the final line."""

    def __init__(self, path: str) -> None:
        import serial

        self.ser = serial.Serial(path, 115200, timeout=0.05)
        self.buf = b""

    def line(self, timeout_s: float = 5.0) -> str | None:
        t_end = time.monotonic() + timeout_s
        while b"\n" not in self.buf:
            if time.monotonic() > t_end:
                return None
            self.buf += self.ser.read(max(1, self.ser.in_waiting))
        raw, self.buf = self.buf.split(b"\n", 1)
        return raw.decode("ascii")

    def raw(self, data: bytes, timeout_s: float = 5.0) -> list[str]:
        self.ser.write(data)
        out = []
        while True:
            line = self.line(timeout_s)
            assert line is not None, f"no final line after {data!r}: {out}"  # never a hang
            out.append(line)
            if line == "ok" or line.startswith("error:"):
                return out

    def cmd(self, text: str, timeout_s: float = 5.0) -> list[str]:
        return self.raw(text.encode("ascii") + b"\n", timeout_s)

    def fields(self, text: str) -> dict[str, str]:
        lines = self.cmd(text)
        assert lines[-1] == "ok", lines
        return dict(w.split("=", 1) for w in lines[0].split()[1:] if "=" in w)

    def close(self) -> None:
        self.ser.close()


@pytest.fixture(scope="module")
def board(built):
    elf, harness = built
    with fw.EmulatedBoard(elf, harness) as b:
        port = Port(b.port)
        b.reset()  # the banner of a reset (after what was left of the power-up banner when the port opened)
        assert port.line().endswith("BOOT name=gonio-detector version=0.1.0 reset=external")
        yield b, port
        port.close()


def read_values(port: Port, cmd: str) -> tuple[dict[str, str], list[int]]:
    f = port.fields(cmd)
    return f, [int(v) for v in f["values"].split(",")]


def test_identifies_as_a_detector_only_controller(board):
    _, port = board
    assert port.fields("ID?") == {"name": "gonio-detector", "version": "0.1.0", "motion": "none", "axes": "-",
                                  "detector": "photodiode"}
    words = port.cmd("help")[0].split()[1:]
    assert {"READ", "DARK", "DETECTOR?", "INT", "INT?", "GAIN", "GAIN?", "TIME?", "DWELL"} <= set(words)
    assert "SAMPLE" not in words  # no sample changer: the driver asks the operator
    d = port.fields("DETECTOR?")
    assert d["bits"] == "10" and d["gains"] == "1,10,100,1000,10000"
    assert float(d["t_int"]) == T_INT and int(d["saturation"]) == 1023 * NCONV


def test_read_sums_the_conversions_of_the_adc_input(board):
    b, port = board
    for mv, code in ((1000.0, 204), (2500.0, 511), (0.0, 0)):  # floor(1023 mV / 5000)
        b.set_adc(mv)
        f, vals = read_values(port, "READ 3")
        assert vals == [code * NCONV] * 3 and f["sat"] == "0" and f["n"] == "3"
        assert float(f["mean"]) == code * NCONV and float(f["std"]) == 0 and float(f["t_int"]) == T_INT
    b.set_counts(123.4)  # counts per conversion, without dither: rounded
    assert read_values(port, "READ 1")[1] == [123 * NCONV]
    b.set_adc(6000.0)  # beyond AVcc: every conversion clips
    f, vals = read_values(port, "READ 2")
    assert vals == [1023 * NCONV] * 2 and f["sat"] == "2"


def test_dark_switches_the_source_off_and_gain_switches_the_multiplexer(board):
    b, port = board
    seen = []

    def on_sync(ev: fw.SyncEvent) -> float:
        seen.append(ev)
        return 100.0 if ev.source else 2.0  # the lamp's light only reaches the ADC with the source pin high

    b.on_sync = on_sync
    b.send("SYNC 1")
    try:
        _, dark = read_values(port, "DARK 2")
        _, light = read_values(port, "READ 2")
        assert dark == [2 * NCONV] * 2 and light == [100 * NCONV] * 2
        assert [ev.source for ev in seen[:4]] == [False, False, True, True]
        assert [ev.first for ev in seen[:4]] == [True, False, True, False] and {ev.n for ev in seen[:4]} == {2}
        assert b.wait_for(lambda: b.source)  # the source is on again between readings
        assert port.cmd("SOURCE OFF") == ["ok"] and b.wait_for(lambda: not b.source)  # another detector's dark
        assert port.fields("SOURCE?") == {"source": "OFF"}
        f, vals = read_values(port, "READ 1")  # a READ with the source off reads dark
        assert vals == [2 * NCONV] and seen[-1].source is False and not b.source
        assert port.cmd("source on") == ["ok"] and b.wait_for(lambda: b.source)
        assert port.cmd("SOURCE MAYBE") == ["error:2"]
        for gain, gsel in ((100, 2), (10000, 4), (1, 0)):
            assert port.cmd(f"GAIN {gain}") == ["ok"]
            assert b.wait_for(lambda gsel=gsel: b.gsel == gsel), (gain, b.events[-3:])
            assert port.fields("GAIN?") == {"gain": str(gain)}
        assert port.cmd("GAIN 1e3") == ["ok"] and b.wait_for(lambda: b.gsel == 3)
        assert port.cmd("GAIN 7") == ["error:2"] and b.gsel == 3  # not one of the amplifier's gains
        read_values(port, "READ 1")
        assert seen[-1].gsel == 3
    finally:
        b.send("SYNC 0")
        b.on_sync = None
        port.cmd("GAIN 1")


def test_integration_time_is_a_whole_number_of_sample_periods(board):
    b, port = board
    b.set_adc(1000.0)
    try:
        for asked, used in (("0.001", 0.001), ("1e-05", 0.000125), ("0.0123", 0.01225), ("0.00019", 0.00025)):
            assert port.cmd(f"INT {asked}") == ["ok"]
            assert float(port.fields("INT?")["t_int"]) == pytest.approx(used, abs=1e-12)
            f, vals = read_values(port, "READ 1")
            nconv = round(used / 125e-6)
            assert float(f["t_int"]) == pytest.approx(used, abs=1e-12) and vals == [204 * nconv]
            assert int(port.fields("DETECTOR?")["saturation"]) == 1023 * nconv
        for bad in ("0", "11", "-1", "abc", "1e", "nan", ""):
            assert port.cmd(f"INT {bad}".strip()) == ["error:2"], bad
    finally:
        port.cmd(f"INT {T_INT}")


def test_time_counts_integration_and_dwell(board):
    _, port = board
    t0 = float(port.fields("TIME?")["t"])
    port.fields("READ 5")
    t1 = float(port.fields("TIME?")["t"])
    assert port.cmd("DWELL 0.25") == ["ok"]
    t2 = float(port.fields("TIME?")["t"])
    assert 5 * T_INT <= t1 - t0 < 5 * T_INT + 0.05  # simulated time: held while the board waits for a command
    assert 0.25 <= t2 - t1 < 0.3
    assert float(port.fields("STATUS?")["t"]) >= t2 and port.fields("?")["state"] == "Idle"


def test_errors_are_answered_and_never_hang(board):
    _, port = board
    assert port.cmd("FOO") == ["error:1"]
    assert port.cmd("read 0") == ["error:2"] and port.cmd("READ 1001") == ["error:2"]
    assert port.cmd("READ x") == ["error:2"] and port.cmd("READ 1 2") == ["error:2"]
    assert port.cmd("x" * 257) == ["error:4"]
    assert port.cmd("ID? " + "y" * 252)[-1] == "error:2"  # 256 characters: not too long
    for word in ("MOVE L100", "HOME", "SAMPLE REF", "SAMPLE?"):
        assert port.cmd(word) == ["error:10"], word  # no axes, no sample changer on this board
    assert port.raw(b"\xff\x00RE\x80AD\n") == ["error:1"]  # garbage bytes in a line
    noise = bytes(b for b in range(256) if b not in (10, 13))
    assert port.raw(noise[:200] + b"\n") == ["error:1"]  # noise within a line's length
    assert port.raw(noise * 4 + b"\n") == ["error:4"]  # a long burst of noise, then an end of line
    port.ser.write(b"\r\n  \n")
    assert port.fields("ID?")["name"] == "gonio-detector"  # the board still answers, nothing left over


def test_acquisition_driver_reads_the_board(board):
    """acquisition's SerialDetector (the driver gonio-capture uses) accepts the firmware's replies: it checks
    mean and std against the values (exact to 3 decimals, here with dithered conversions), t_int, gain, sat."""
    from acquisition.devices.serial_link import SerialDetector, SerialLink

    b, port = board
    port.close()
    b.set_counts(300.3)
    b.set_dither(0.7)
    link = SerialLink(b.port, timeout_s=2.0, retries=0, name="detector board")
    try:
        det = SerialDetector(link, "photodiode", T_INT, 65535.0, gains=(1.0, 10.0, 100.0), start_gain=10.0)
        det.connect()
        assert (det.has_time, det.has_dwell, det.has_sample_changer) == (True, True, False)
        assert det.gain == 10.0 and b.wait_for(lambda: b.gsel == 1)
        rd = det.read(16)
        assert rd.mean[0] == pytest.approx(300.3 * NCONV, abs=3.0) and rd.std[0] > 1.0 and rd.saturated == 0
        assert det.set_integration_time(0.5) == 0.5
        rd = det.read(3)  # 4000 conversions a repeat: sums near 1.2e6, std from 3 values, all exact
        assert rd.mean[0] == pytest.approx(300.3 * 4000, rel=1e-3) and rd.std[0] > 0
        dark = det.dark(2)
        assert dark.n == 2 and det.time() > 2.0
    finally:
        link.close()
        b.set_dither(0.0)
        port.ser.open()
