"""The detector firmware's light that is the source's alone (CHOP ON under room light and 100 Hz flicker), its
monitor photodiode (MONITOR=1: the ratio divides the source's drift out), its clip at the op-amp's swing and its
source settle time, on the emulated board fed by the simulator's physics (room light, flicker and drift are the
simulator's world: [simulator].ambient, flicker_depth, flicker_hz, source_drift_per_h, monitor_mv).

Skipped, with the reason, without avr-gcc and simavr (scripts/system-packages.sh installs them)."""

from __future__ import annotations

import re

import numpy as np
import pytest

from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from simulator.devices import firmware as fw
from tests.test_acq_support import make_raw
from tests.test_firmware import Port, read_values

CONFIG_H = fw.FIRMWARE_DIR / "src" / "config.h"

PROBLEM = fw.toolchain_problem()
pytestmark = pytest.mark.skipif(PROBLEM is not None, reason=f"firmware tests skipped: {PROBLEM}")

#: a white Lambertian seen at (0, 45) deg: 405 counts at gain 1 over 0.02 s, 25 counts a conversion at gain 10
WORLD = {"material": {"name": "white", "lobes": [{"type": "lambert", "albedo": 0.9}]},
         "simulator": {"source_power": 1.0e6, "dark_offset": 200.0, "read_noise": 5.0, "input_offset": 0.2,
                       "input_noise": 0.003, "electrons_per_count": 1000.0}}
GAIN = 10
N = 16


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("firmware")
    try:
        return fw.build_firmware(d / "fw", monitor=True), fw.build_harness(d)
    except fw.FirmwareError as e:
        pytest.skip(f"firmware tests skipped: {e}")


@pytest.fixture()
def rig(built):
    """The board fed by a bench's physics (arms fixed at theta_i = 0, theta_o = 45 deg)."""
    elf, harness = built
    bench = VirtualBench(config_from_dict(make_raw(WORLD)))
    board = fw.EmulatedBoard(elf, harness, dither_lsb=0.5, seed=3)
    feed = fw.PhysicsFeed(bench.physics, bench.clock, lambda t: (0.0, 45.0), bench.lock,
                          (1.0, 10.0, 100.0, 1000.0, 10000.0))
    feed.attach(board)
    port = Port(board.port)
    board.reset()
    line = port.line()  # what was left of the power-up banner may come first (an empty line on a busy machine)
    for _ in range(3):
        if line is None or "BOOT" in line:
            break
        line = port.line()
    assert line is not None and "BOOT" in line, line
    assert port.cmd(f"GAIN {GAIN}") == ["ok"] and port.cmd("INT 0.02") == ["ok"]
    yield bench.physics, board, port
    port.close()
    board.close()


def stats(values: list[int]) -> tuple[float, float]:
    """mean and its standard error"""
    v = np.asarray(values, dtype=float)
    return float(v.mean()), float(v.std(ddof=1) / np.sqrt(v.size))


def test_chopped_reading_under_room_light_is_the_dark_room_reading(rig):
    physics, board, port = rig
    # the dark room: READ - DARK, unchopped
    f_read, lit = read_values(port, f"READ {N}")
    _, dark = read_values(port, f"DARK {N}")
    signal = np.asarray(lit, float) - np.asarray(dark, float)
    s_mean, s_err = stats(list(signal))
    assert 3000 < s_mean < 5000  # 405 counts at gain 1 over 0.02 s, x 10
    # room light at 10 x the signal, flickering at 100 Hz by +-50 %
    physics.ambient = 10 * s_mean / GAIN / 2  # [simulator].ambient is over the configured 0.01 s
    physics.flicker_depth = 0.5
    _, plain = read_values(port, f"READ {N}")
    p_mean, _ = stats(plain)
    assert p_mean - np.mean(lit) > 8 * s_mean  # the plain reading is off by the room light
    assert port.cmd("CHOP ON") == ["ok"] and port.fields("CHOP?") == {"chop": "ON", "half": "0.02"}
    f, chopped = read_values(port, f"READ {N}")
    assert f["t_int"] == "0.02" and f["sat"] == "0"
    c_mean, c_err = stats(chopped)
    assert abs(c_mean - s_mean) < 3 * np.hypot(c_err, s_err), (c_mean, s_mean, c_err, s_err)
    # what chopping leaves of the room light alone (source kept off): nothing, within noise
    _, residual = read_values(port, f"DARK {N}")
    r_mean, r_err = stats(residual)
    assert abs(r_mean) < 3 * r_err + 1, (r_mean, r_err)
    # the source switched in every half, and back on after the reading
    assert board.wait_for(lambda: board.source)
    assert port.cmd("CHOP OFF") == ["ok"] and port.fields("DETECTOR?")["chop"] == "OFF"


def test_chopping_halves_cancel_flicker_that_a_plain_reading_aliases(rig):
    """At 5 ms (half a flicker period) a plain reading's repeats scatter with the flicker's phase; chopped ones do
    not (each half integrates whole periods)."""
    physics, board, port = rig
    physics.ambient = 5000.0
    physics.flicker_depth = 0.8
    assert port.cmd("INT 0.005") == ["ok"]
    _, plain = read_values(port, f"READ {N}")
    _, dark = read_values(port, f"DARK {N}")
    plain_scatter = np.std(np.asarray(plain, float) - np.asarray(dark, float), ddof=1)
    assert port.cmd("CHOP ON") == ["ok"]
    f, chopped = read_values(port, f"READ {N}")
    assert f["t_int"] == "0.02"  # rounded up to one whole chopping half
    # compare per unit of integration time: the chopped reading integrates 4 x longer
    assert plain_scatter * 4 > 10 * np.std(chopped, ddof=1), (plain_scatter, np.std(chopped, ddof=1))
    port.cmd("CHOP OFF")


def test_the_monitor_ratio_divides_the_source_drift_out(rig):
    physics, board, port = rig
    physics.source_drift_per_h = 0.5  # a lamp that loses or gains half its power in an hour: 5 % in 6 min
    dark = port.fields("DARK 8")
    assert int(dark["monitor"]) < 10  # the monitor sees the source only (0 V, the dither's few counts)
    first = port.fields("READ 8")
    assert port.cmd("DWELL 360") == ["ok"]  # six minutes of bench time
    later = port.fields("READ 8")
    sig0, sig1 = (float(r["mean"]) - float(dark["mean"]) for r in (first, later))
    raw = sig1 / sig0
    ratio = (sig1 / float(later["monitor"])) / (sig0 / float(first["monitor"]))
    assert raw == pytest.approx(1.05, abs=0.005)  # the signal follows the source
    assert ratio == pytest.approx(1.0, abs=0.002)  # the ratio does not


def test_clip_at_the_op_amps_swing_and_settle(rig):
    physics, board, port = rig
    board.on_sync = None
    board.send("SYNC 0")
    d = port.fields("DETECTOR?")
    assert d["clip"] == "1012"  # floor(1023 x 4950 mV / 5000 mV): the MCP6001's swing minus 25 mV
    board.set_adc(4960.0)  # an op-amp at its rail never reads 1023; the old test (v >= 1023) missed it
    f = port.fields("READ 2")
    assert f["sat"] == "2"
    board.set_adc(4900.0)
    assert port.fields("READ 2")["sat"] == "0"
    gain_settle_us = int(re.search(r"#define\s+GAIN_SETTLE_US\s+(\d+)", CONFIG_H.read_text()).group(1))
    assert port.fields("SETTLE?") == {"source": "0.002", "gain": f"{gain_settle_us * 1e-6:g}"}
    assert port.cmd("SETTLE 0.3") == ["ok"] and port.fields("SETTLE?")["source"] == "0.3"
    assert port.cmd("SETTLE 11") == ["error:2"] and port.cmd("SETTLE x") == ["error:2"]
    t0 = float(port.fields("TIME?")["t"])
    port.fields("DARK 1")  # the source switches off: the dark waits for the lamp to go dark
    t1 = float(port.fields("TIME?")["t"])
    assert 0.3 + 0.02 <= t1 - t0 < 0.3 + 0.07  # the settle, the integration, the monitor's, the reply
    assert port.cmd("SOURCE OFF") == ["ok"]
    port.fields("DARK 1")  # the source went off with SOURCE OFF: this one waits
    t0 = float(port.fields("TIME?")["t"])
    port.fields("DARK 1")  # already off and settled: no wait
    port.fields("DARK 1")
    assert float(port.fields("TIME?")["t"]) - t0 < 0.2


def test_the_driver_chops_reads_the_saturation_after_int_and_knows_a_dc_amplifier(rig):
    """acquisition's SerialDetector on the board: [detector].chop sends CHOP ON; the saturation is the board's for
    the integration time set (read again after INT), and amplifier=dc makes auto-ranging use the gains only."""
    from acquisition.devices.autorange import AutoRanger
    from acquisition.devices.serial_link import SerialDetector, SerialLink

    physics, board, port = rig
    port.close()
    physics.ambient = 1000.0  # the Python physics clips a repeat's sum at 65535 counts: kept below it
    link = SerialLink(board.port, timeout_s=20.0, retries=0, name="detector board")  # busy machine
    try:
        det = SerialDetector(link, "photodiode", 0.01, 1e12, gains=(1.0, 10.0, 100.0, 1000.0, 10000.0),
                             start_gain=10.0)
        det.chop = True
        det.connect()
        assert det.dc_amplifier and det.integration_time_s == 0.02  # rounded to one chopping half
        assert det.saturation == 1023 * 160
        assert det.set_integration_time(0.04) == 0.04 and det.saturation == 1023 * 320  # read after INT
        rd = det.read(4)
        assert rd.saturated == 0 and 2 * 3000 < rd.mean[0] < 2 * 5000  # the source's light alone, 2 halves of it
        ranger = AutoRanger(det, 0.04, 1e-5, read_dark=lambda: det.dark(2), gains=det.gains)
        assert set(ranger.ladder) == {0.04}  # no shorter integration time: it would not lower a conversion
    finally:
        link.close()


def test_a_usb_detectors_dark_through_the_board_waits_the_sources_settle_time(rig):
    """A spectrometer's dark through the board's SOURCE pin (acquisition.devices.board.BoardBacked): the driver
    reads SETTLE? and dwells that long after each switch, and marks the switch (its next scan is discarded)."""
    from acquisition.calibration import Reading
    from acquisition.devices.board import BoardBacked
    from acquisition.devices.serial_link import SerialLink

    physics, board, port = rig
    assert port.cmd("SETTLE 0.3") == ["ok"]  # a halogen lamp
    port.close()
    link = SerialLink(board.port, timeout_s=20.0, retries=0, name="detector board")  # busy machine
    try:
        b = BoardBacked(link, "board", name="spectrometer")
        b.connect_board()
        assert b.dark_way == "board" and b.source_settle_s == 0.3
        seen: list[float] = []

        def scan(n: int) -> Reading:
            seen.append(board.time())  # the emulation's clock, the one its PIN lines are stamped with
            return Reading(np.zeros(1), np.zeros(1), n)

        t0 = board.time()
        b.with_source_off(scan, 4)
        t1 = board.time()
        # the pin's changes by the emulation's clock, each stamped with the cycle the firmware wrote the port at (the
        # harness's PIN lines may reach this process late on a busy machine: judged by when, not by arrival)
        assert board.wait_for(lambda: any(not src for t, _, src in board.pin_history if t >= t0) and board.source,
                              20.0)
        changes = [(t, src) for t, _, src in board.pin_history if t >= t0]
        t_off = next(t for t, src in changes if not src)
        t_on = next(t for t, src in changes if src and t > t_off)
        assert t_off <= seen[0] - 0.3 and seen[0] < t_on  # read dark, 0.3 s after the switch, the source off
        assert t1 - t_on >= 0.3  # on again, and settled before the next reading
        assert b.source_switched  # the spectrometer's next scan began before the switch: discarded
    finally:
        link.close()
