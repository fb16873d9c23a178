"""The emulated detector board reads light through the amplifier's circuit: the firmware (on simavr) behind the
simulator's physics and the ngspice transfer table of hardware/frontend/frontend.cir reads a light level that
grows tenfold a range; the same board behind the table of the guide's old wiring (anode on the inverting input,
made here by ngspice from a scratch copy of the netlist) reads no light at all, so a wrong circuit fails.

Skipped, with the reason, without avr-gcc and simavr, or without ngspice (the old wiring's table)."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from hardware.frontend import simulate as sim
from simulator.devices import firmware as fw

PROBLEM = fw.toolchain_problem() or sim.ngspice_problem()
pytestmark = [pytest.mark.skipif(PROBLEM is not None, reason=f"board-through-the-circuit tests skipped: {PROBLEM}"),
              pytest.mark.slow]

REPO = Path(__file__).resolve().parents[1]


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("firmware")
    try:
        return fw.build_firmware(d / "fw"), d
    except fw.FirmwareError as e:
        pytest.skip(f"board-through-the-circuit tests skipped: {e}")


@pytest.fixture(scope="module")
def old_wiring_table(tmp_path_factory) -> Path:
    """The transfer table of the guide's old wiring, made by ngspice from a scratch copy of the netlist."""
    d = tmp_path_factory.mktemp("old-wiring")
    for p in sim.NETLIST.parent.glob("*.lib"):
        shutil.copy(p, d / p.name)
    text = sim.NETLIST.read_text()
    assert "XD1 vref inn photodiode" in text
    (d / "frontend.cir").write_text(text.replace("XD1 vref inn photodiode", "XD1 inn vref photodiode"))
    assert sim.main(["--table", "--netlist", str(d / "frontend.cir"), "--out", str(d / "transfer.json")]) == 0
    return d / "transfer.json"


def light_per_range(built, table: Path | None) -> dict[int, float]:
    """READ minus DARK (counts, 8 repeats of 10 ms) on each of the firmware's gains, the arms where the simulated
    bench starts (theta_i 0, theta_o 45 deg on the blue plastic)."""
    from simulator.bench import VirtualBench
    from simulator.config import load_config
    from tests.test_firmware import Port

    elf, build_dir = built
    bench = VirtualBench(load_config(REPO / "configs" / "simulated.toml"))
    board, _ = fw.start_firmware_detector(bench, elf, build_dir=build_dir, frontend_table=table)
    out = {}
    port = Port(board.port)
    try:
        lines = port.cmd("ID?")  # the start-up banner (BOOT ...) may come first on a busy machine
        assert lines[-1] == "ok" and any(w.startswith("ID name=gonio-detector") for w in lines), lines
        for gain in (1, 10, 100, 1000):
            assert port.cmd(f"GAIN {gain}")[-1] == "ok"
            out[gain] = float(port.fields("READ 8")["mean"]) - float(port.fields("DARK 8")["mean"])
    finally:
        port.close()
        board.close()
    return out


def test_the_board_reads_light_tenfold_a_range_through_the_circuit(built):
    light = light_per_range(built, None)
    assert light[100] > 2000, light  # the blue plastic at 45 deg: about 50 mV a conversion on the 1 M range
    for lo, hi in ((10, 100), (100, 1000)):
        assert light[hi] / light[lo] == pytest.approx(10.0, rel=0.05), light


def test_the_guides_old_wiring_makes_the_board_read_no_light(built, old_wiring_table):
    light = light_per_range(built, old_wiring_table)
    assert all(v <= 80 for v in light.values()), light  # at most a count a conversion: nothing of the light
