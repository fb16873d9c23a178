"""Captures on the emulated detector board: it agrees with the Python simulator, and it survives the faults of a
real bench.

Faults of a real bench on the emulated detector board (the firmware of firmware/detector on simavr, behind the
simulator's Dynamixel arms, as ``gonio-sim serve --detector-firmware`` runs it): the board reset mid-reading (its
banner arrives), the USB cable pulled mid-sweep, a board that hangs, a line of noise. The capture stops safely with
one line saying what happened and the arms parked (or rides the noise out), and ``--resume`` completes the slice
without losing or doubling a sample. Skipped, with the reason, without avr-gcc and simavr."""

from __future__ import annotations

import numpy as np
import pytest
import tomli_w

from acquisition.cli import main
from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from simulator.devices import firmware as fw
from simulator.ports.transports import PtyServer
from tests.helpers import planned
from tests.test_acq_support import base_raw, keys, make_raw, read

PROBLEM = fw.toolchain_problem()
pytestmark = pytest.mark.skipif(PROBLEM is not None, reason=f"firmware tests skipped: {PROBLEM}")

#: a short sweep: one incidence, 12 deg steps; short darks and reference
PLAN = {"plan": {"theta_i_deg": [40.0], "theta_o_step_deg": 12.0, "repeats": 4},
        "detector": {"dark_repeats": 8}, "calibration": {"reference_repeats": 8},
        "bench": {"serial_timeout_s": 0.6},
        "motion": {"retries": 6}}  # the Dynamixel SDK's wall-clock deadline misses on a loaded machine: retried


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("firmware")
    try:
        return fw.build_firmware(d / "fw", sample_changer=True), d
    except fw.FirmwareError as e:
        pytest.skip(f"firmware tests skipped: {e}")


class Rig:
    """One simulated Dynamixel bench in this process, its detector the emulated board; ``fault(board)`` is called
    at the first repeat of reading number ``at`` (darks and the white reference count)."""

    def __init__(self, tmp_path, built, fault, at: int = 16) -> None:
        self.elf, self.build_dir = built
        self.tmp = tmp_path
        self.raw = make_raw(PLAN)
        self.bench = VirtualBench(config_from_dict(self.raw, base_dir=tmp_path, source="rig"))
        self.server = PtyServer(self.bench, names=("dynamixel",))
        self.fault, self.at, self.readings, self.boards, self.runs = fault, at, 0, [], 0
        self.plug_in()

    def plug_in(self) -> None:
        """A (new) board: the first one, or the one plugged in again after the cable was pulled."""
        board, feed = fw.start_firmware_detector(self.bench, self.elf, build_dir=self.build_dir)
        self.boards.append(board)

        def on_sync(ev: fw.SyncEvent) -> float:
            if ev.first:
                self.readings += 1
                if self.readings == self.at and self.fault is not None:
                    self.fault(board)
            return feed(ev)

        board.on_sync = on_sync

    def capture(self, out, resume: bool = False) -> int:
        raw = dict(self.raw)
        raw["bench"] = {**raw["bench"], "transport": "dynamixel", "dynamixel_port": self.server.paths()["dynamixel"],
                        "serial_port": self.boards[-1].port}
        self.runs += 1
        cfg = self.tmp / f"run{self.runs}.toml"
        cfg.write_text(tomli_w.dumps(raw))
        self.cfg = cfg
        return main(["--config", str(cfg), "--out", str(out), "--no-progress"] + (["--resume"] if resume else []))

    def parked(self) -> bool:
        ti, to = self.bench.arm_angles()
        park = base_raw()["axes"]
        return abs(ti - park["light"]["park_deg"]) < 0.5 and abs(to - park["detector"]["park_deg"]) < 0.5

    def close(self) -> None:
        for b in self.boards:
            b.close()
        self.server.close()


@pytest.fixture
def rig_factory(tmp_path, built):
    rigs = []

    def make(fault, at: int = 16) -> Rig:
        rigs.append(Rig(tmp_path, built, fault, at))
        return rigs[-1]

    yield make
    for r in rigs:
        r.close()


def stopped_then_resumed(rig: Rig, capsys, tmp_path, expect: str, before_resume=None) -> str:
    out = tmp_path / "out"
    assert rig.capture(out) == 1
    err = capsys.readouterr().err
    first = next(ln for ln in err.splitlines() if ln.startswith("gonio-capture:"))
    assert expect in first, err  # one line says what happened
    assert "--resume" in err and "safely in" in err, err
    assert rig.parked(), rig.bench.arm_angles()
    n_before = len(read(out / "slice.csv")) if (out / "slice.csv").exists() else 0
    assert 0 < n_before < len(planned(rig.cfg))
    if before_resume is not None:
        before_resume()
    rig.fault = None
    assert rig.capture(out, resume=True) == 0, capsys.readouterr().err
    s = read(out / "slice.csv")  # the reader refuses a sample recorded twice
    assert sorted(keys(s)) == planned(rig.cfg)  # none lost
    return first


def test_board_reset_mid_reading_stops_safely_and_resumes(rig_factory, capsys, tmp_path):
    rig = rig_factory(lambda board: board.reset())
    line = stopped_then_resumed(rig, capsys, tmp_path, "the board restarted")
    assert "BOOT name=gonio-detector" in line and "reset=external" in line


def test_pulled_cable_mid_sweep_stops_safely_and_resumes_on_the_board_plugged_in_again(rig_factory, capsys,
                                                                                      tmp_path):
    rig = rig_factory(lambda board: board.unplug())
    stopped_then_resumed(rig, capsys, tmp_path, "is the controller still connected?", before_resume=rig.plug_in)


def test_silent_board_stops_safely_and_resumes(rig_factory, capsys, tmp_path):
    rig = rig_factory(lambda board: board.freeze(True))
    def power_cycle() -> None:  # what the operator does to a hung board (it would run the queued commands else)
        rig.boards[-1].freeze(False)
        rig.boards[-1].reset()

    stopped_then_resumed(rig, capsys, tmp_path, "no valid reply", before_resume=power_cycle)


def test_line_of_noise_is_retried_and_the_capture_completes(rig_factory, capsys, tmp_path):
    rig = rig_factory(lambda board: board.noise(b"\x15\xfe~#garbage\xff\r\n"))
    out = tmp_path / "out"
    assert rig.capture(out) == 0, capsys.readouterr().err
    assert sorted(keys(read(out / "slice.csv"))) == planned(rig.cfg)
    assert "retrying" in (out / "capture.log").read_text()  # the noise did arrive, and was read again


def test_capture_on_the_firmware_agrees_with_the_python_simulator(rig_factory, tmp_path, capsys):
    """The same sweep, the same seed: on the firmware (10-bit ADC, 80 dithered conversions a repeat) and on the
    Python controller (the same noise draws). The samples differ by the ADC's quantisation only: well within a
    sample's std on average, never by many (a wrong gain, pin or timing would be off by far more)."""
    rig = rig_factory(None)
    assert rig.capture(tmp_path / "fw") == 0, capsys.readouterr().err
    fw_slice = read(tmp_path / "fw" / "slice.csv")
    py_bench = VirtualBench(config_from_dict(rig.raw, base_dir=tmp_path, source="python"))
    with PtyServer(py_bench) as server:
        raw = dict(rig.raw)
        raw["bench"] = {**raw["bench"], "transport": "dynamixel", **{f"{k}_port": v for k, v in
                                                                    server.paths().items()}}
        cfg = tmp_path / "python.toml"
        cfg.write_text(tomli_w.dumps(raw))
        assert main(["--config", str(cfg), "--out", str(tmp_path / "py"), "--no-progress"]) == 0
    py_slice = read(tmp_path / "py" / "slice.csv")
    assert keys(fw_slice) == keys(py_slice)
    z = (fw_slice.values[:, 0] - py_slice.values[:, 0]) / py_slice.std[:, 0]
    assert np.sqrt(np.mean(z ** 2)) < 1.0 and np.max(np.abs(z)) < 4.0, z
    assert np.any(z != 0)  # the board's own quantisation shows: not a copy of the Python controller's numbers
