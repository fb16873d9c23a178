"""simulator/world/frontend.py: the simulator's lookup of the amplifier's committed transfer table (no ngspice
needed), and the physics reading through it ([simulator].frontend = "netlist")."""

from __future__ import annotations

import json

import numpy as np
import pytest

from simulator.config import config_from_dict
from simulator.world import frontend as fe

FE = fe.load_frontend()


def test_the_committed_table_reads_light_on_every_range_as_vref_plus_iph_rf():
    doc = json.loads(fe.TABLE.read_text())
    assert FE.n_ranges == 5
    for k, r in enumerate(doc["ranges"]):
        fs = r["full_scale_a"]
        iph = np.linspace(0.01, 0.9, 30) * fs
        v = FE.output_v(iph, k)
        assert np.all(np.diff(v) > 0)
        assert np.allclose(v - FE.output_v(0.0, k), iph * r["rf_ohm"], rtol=0.02)
        assert 0.02 < FE.output_v(0.0, k) < 0.035  # the 30 mV reference
        top = FE.output_v(np.array([2 * fs, 50 * fs]), k)
        assert np.all((top > 4.9) & (top < 5.0)) and abs(top[0] - top[1]) < 0.005  # clipped at the swing


def test_the_monitor_amplifier_reads_its_photodiode_on_a_fixed_1_megohm():
    imon = np.linspace(0.05e-6, 4.4e-6, 20)
    v = FE.monitor_v(imon)
    assert np.allclose(v - FE.monitor_v(0.0), imon * 1e6, rtol=0.01) and np.all(np.diff(v) > 0)
    assert 4.9 < FE.monitor_v(1e-4) < 5.0  # clipped at the op-amp's swing


def test_output_broadcasts_ranges_and_refuses_a_range_that_is_not_there():
    v = FE.adc_input_mv(np.full(5, 1e-7), np.arange(5))
    assert v.shape == (5,) and np.all(np.diff(v[:4]) > 0) and v[4] > 4900  # 10 uA on 100 M: clipped
    assert FE.output_v(-1e-3, 0) == pytest.approx(FE.v_floor(0))  # light taken away: the bottom rail
    with pytest.raises(ValueError, match="gain index 5"):
        FE.output_v(1e-6, 5)


def test_settling_residual_reaches_a_tenth_of_a_percent_at_the_tables_time():
    t = FE.settle_gain_s[3]
    assert FE.residual(t, 3, "gain") == pytest.approx(1e-3)
    assert FE.residual(0.0, 3) == 1.0 and FE.residual(2 * t, 3) == pytest.approx(1e-6)
    assert FE.residual(FE.settle_source_s[0], 0, "source") == pytest.approx(1e-3)


def test_a_bad_table_is_refused_naming_the_file(tmp_path):
    with pytest.raises(ValueError, match="nothing.json: cannot read"):
        fe.FrontEnd.read(tmp_path / "nothing.json")
    bad = tmp_path / "bad.json"
    bad.write_text('{"ranges": [{"index": 0, "iph_a": [1, 0], "v_out": [0, 1], "settle_gain_s": 1, '
                   '"settle_source_s": 1}]}')
    with pytest.raises(ValueError, match="bad.json: each range needs increasing photocurrents"):
        fe.FrontEnd.read(bad)


def test_the_photocurrent_scale_keeps_the_physics_counts_at_gain_1():
    """AMPS_PER_COUNT: one count per conversion at gain 1 is one LSB (4.888 mV) on an ideal 10 k."""
    assert fe.AMPS_PER_COUNT * 10e3 == pytest.approx(5.0 / 1023)
    counts = FE.reading_counts(np.array([0.0, 8000.0]), 0, 0.01)  # 80 conversions: 100 counts, 48.9 uA each
    assert counts[1] - counts[0] == pytest.approx(8000.0, rel=0.015)
    assert counts[0] == pytest.approx(80 * FE.output_v(0.0, 0) / fe.ADC_LSB_V)


@pytest.mark.parametrize("gain", [1.0, 10.0, 100.0, 1000.0, 10000.0])
def test_physics_through_the_circuit_reads_what_the_ideal_formula_reads_above_its_dark(config_dict, gain):
    """[simulator].frontend = "netlist": the same angles, noiseless, read the same dark-subtracted counts as the
    ideal amplifier within the circuit's gain error (1 % on the 10 k range: the switch's 80 ohm), and the dark is
    the 30 mV reference (about 490 counts of 80 conversions), not dark_offset."""
    from simulator.bench import VirtualBench

    noiseless = {"read_noise": 0.0, "shot_noise": False, "input_noise": 0.0, "input_offset": 0.0,
                 "source_power": 2e7 / gain}
    ideal = VirtualBench(config_from_dict(config_dict({"simulator": noiseless}))).physics
    circ = VirtualBench(config_from_dict(config_dict({"simulator": {**noiseless, "frontend": "netlist"}}))).physics
    assert ideal.frontend is None and circ.frontend is not None
    for p in (ideal, circ):
        p.detector.gain = gain
    ti, to = np.array([30.0, 30.0, 20.0]), np.array([30.0, -10.0, 50.0])
    dark_i = ideal.expected_reading(ti, to, source_on=False)
    dark_c = circ.expected_reading(ti, to, source_on=False)
    assert np.allclose(dark_i, 200.0) and np.all((dark_c > 400) & (dark_c < 520))
    light_i = ideal.expected_reading(ti, to) - dark_i
    light_c = circ.expected_reading(ti, to) - dark_c
    assert np.all(light_i > 500)
    assert np.allclose(light_c, light_i, rtol=0.015), (light_c / light_i)


class PinsOnly:
    """Stands in for the emulated board (simulator.devices.firmware.EmulatedBoard) where the feed looks: its pin
    history (time s, multiplexer channel, source pin), its sample changer pin, and the control lines the feed sends
    it (the room light's flicker and the monitor photodiode: kept, not acted on)."""

    reference = False

    def __init__(self, history):
        self.pin_history = history
        self.sent: list[str] = []

    def send(self, line: str) -> None:
        self.sent.append(line)


def test_the_board_reads_short_of_the_light_while_the_amplifier_settles_after_a_gain_switch(config_dict):
    """The emulated board's feed (PhysicsFeed): a reading that starts 50 us after a switch from range 1 to range 2
    reads between the two ranges' outputs in its first repeats and the settled value once the table's settling
    time has passed; one that starts after the firmware's wait reads settled."""
    from simulator.bench import VirtualBench
    from simulator.devices import firmware as fw

    noiseless = {"read_noise": 0.0, "shot_noise": False, "input_noise": 0.0, "input_offset": 0.0,
                 "frontend": "netlist"}
    bench = VirtualBench(config_from_dict(config_dict({"simulator": noiseless})))
    feed = fw.PhysicsFeed(bench.physics, bench.clock, lambda t: (30.0, 30.0), bench.lock, (1, 10, 100, 1000, 10000))
    feed.board = PinsOnly([(0.5, 0, True), (1.0, 1, True), (2.0, 2, True)])
    early = np.array(feed(fw.SyncEvent(True, 8, 2, 2, True, 2.0 + 50e-6)))
    settled = np.array(feed(fw.SyncEvent(True, 2, 2, 2, True, 2.5)))
    feed.board = PinsOnly([(1.0, 1, True), (2.0, 2, True)])
    after_wait = np.array(feed(fw.SyncEvent(True, 2, 2, 2, True, 2.0 + 0.0025)))
    before = np.array(feed(fw.SyncEvent(True, 1, 2, 1, True, 1.9)))  # the same light on range 1
    assert settled[0] > 5 * before[0]  # ten times the light above the dark, once settled
    assert before[0] < early[0] < 0.9 * settled[0] and np.all(np.diff(early) > 0)
    assert early[-1] == pytest.approx(settled[0], rel=1e-3)  # 2 ms later: settled
    assert after_wait[0] == pytest.approx(settled[0], rel=1e-3)


def test_extra_photocurrent_adds_before_the_circuit_and_clips_with_it():
    """Light that is not the source's (the room's) adds in amps before the amplifier: a reading it pushes past
    the op-amp's swing is clipped, not the sum of two readings."""
    base = FE.reading_counts(np.array([10.0]), 2, 0.01)
    more = FE.reading_counts(np.array([10.0]), 2, 0.01, extra_a=1e-7)
    assert more[0] - base[0] == pytest.approx(80 * 1e-7 * 1e6 / fe.ADC_LSB_V, rel=0.01)  # 0.1 V a conversion
    top = FE.reading_counts(np.array([10.0]), 2, 0.01, extra_a=1e-3)
    assert top[0] == pytest.approx(80 * FE.output_v(1.0, 2) / fe.ADC_LSB_V)


def test_the_dynamic_range_figure_models_the_ads1115_as_the_firmware_configures_it():
    """hardware/frontend/simulate.py's ADS1115 (docs/build-a-bench.md's decades) is the one the firmware sets up:
    its config word's PGA, data rate and multiplexer (firmware/detector/src/ads1115.h, datasheet SBAS444 table 8)."""
    import re
    from pathlib import Path

    from hardware.frontend.simulate import ADCS

    header = (Path(__file__).resolve().parents[1] / "firmware" / "detector" / "src" / "ads1115.h").read_text()
    word = int(re.search(r"#define ADS1115_CONFIG_START (0x[0-9A-Fa-f]+)u", header).group(1), 16)
    fsr_v = {0: 6.144, 1: 4.096, 2: 2.048, 3: 1.024, 4: 0.512}.get((word >> 9) & 0b111, 0.256)
    rate_sps = (8, 16, 32, 64, 128, 250, 475, 860)[(word >> 5) & 0b111]
    adc = ADCS["ADS1115 16-bit"]
    assert adc["top_v"] == fsr_v and adc["lsb_v"] == pytest.approx(fsr_v / 32768)
    assert adc["band_hz"] == pytest.approx(rate_sps / 2)  # one conversion's sinc filter
    assert adc.get("differential") is ((word >> 12) & 0b111 == 0)  # MUX 000: AIN0 - AIN1 (out - Vref)
