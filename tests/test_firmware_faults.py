"""Captures on the emulated detector board: it agrees with the Python simulator, and it survives the faults of a
real bench.

Faults of a real bench on the emulated detector board (the firmware of firmware/detector on simavr, behind the
simulator's Dynamixel arms, as ``gonio-sim serve --detector-firmware`` runs it): the board reset mid-reading (its
banner arrives), the USB cable pulled mid-sweep, a board that hangs, a line of noise. The capture stops safely with
one line saying what happened and the arms parked (or rides the noise out), and ``--resume`` completes the slice
without losing or doubling a sample. Skipped, with the reason, without avr-gcc and simavr."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import tomli_w

from acquisition.cli import main
from simulator.devices import firmware as fw
from tests.helpers import planned
from tests.test_acq_support import base_raw, keys, make_raw, read

RIG = Path(__file__).with_name("firmware_rig.py")
PROBLEM = fw.toolchain_problem()
pytestmark = pytest.mark.skipif(PROBLEM is not None, reason=f"firmware tests skipped: {PROBLEM}")

#: a short sweep: one incidence, 12 deg steps; short darks and reference
PLAN = {"plan": {"theta_i_deg": [40.0], "theta_o_step_deg": 12.0, "repeats": 4},
        "detector": {"dark_repeats": 8}, "calibration": {"reference_repeats": 8},
        "bench": {"serial_timeout_s": 0.5},
        "motion": {"retries": 12},  # the Dynamixel SDK's wall-clock deadline misses on a loaded machine: retried
        "simulator": {"frontend": "netlist"}}  # the Python controller reads the amplifier's circuit, as the board does


@pytest.fixture(scope="module")
def built(tmp_path_factory):
    d = tmp_path_factory.mktemp("firmware")
    try:
        return fw.build_firmware(d / "fw", sample_changer=True), d
    except fw.FirmwareError as e:
        pytest.skip(f"firmware tests skipped: {e}")


class Rig:
    """A simulated Dynamixel bench with the emulated board as its detector, in a process of its own
    (tests/firmware_rig.py); ``fault`` strikes the board at the first repeat of its reading number ``at``."""

    def __init__(self, tmp_path, built, fault: str, at: int = 16, *overs: dict) -> None:
        elf, build_dir = built
        self.tmp, self.runs = tmp_path, 0
        self.raw = make_raw(PLAN, *overs)
        cfg = tmp_path / "rig.toml"
        cfg.write_text(tomli_w.dumps(self.raw))
        self.proc = subprocess.Popen([sys.executable, str(RIG), str(cfg), str(elf), str(build_dir), fault, str(at)],
                                     stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, bufsize=1)
        self.ports = self._reply()

    def _reply(self):
        line = self.proc.stdout.readline()
        assert line, "the rig stopped"
        return json.loads(line)

    def ask(self, cmd: str):
        self.proc.stdin.write(cmd + "\n")
        return self._reply()

    def plug_in(self) -> None:
        """The board plugged in again after the cable was pulled (a new port)."""
        self.ports.update(self.ask("plug"))

    def capture(self, out, resume: bool = False) -> int:
        raw = dict(self.raw)
        raw["bench"] = {**raw["bench"], "transport": "dynamixel", "dynamixel_port": self.ports["dynamixel"],
                        "serial_port": self.ports["serial"]}
        self.runs += 1
        self.cfg = self.tmp / f"run{self.runs}.toml"
        self.cfg.write_text(tomli_w.dumps(raw))
        return main(["--config", str(self.cfg), "--out", str(out), "--no-progress"] + (["--resume"] if resume else []))

    def parked(self) -> bool:
        ti, to = self.ask("angles")
        park = base_raw()["axes"]
        return abs(ti - park["light"]["park_deg"]) < 0.5 and abs(to - park["detector"]["park_deg"]) < 0.5

    def close(self) -> None:
        try:
            self.proc.stdin.write("quit\n")
            self.proc.stdin.close()
            self.proc.wait(timeout=10)
        except Exception:
            self.proc.kill()
            self.proc.wait()


@pytest.fixture(scope="module")
def built_monitor(tmp_path_factory):
    """The board with a monitor photodiode on A1 (MONITOR=1): READ reports monitor=<sum>."""
    d = tmp_path_factory.mktemp("firmware-monitor")
    try:
        return fw.build_firmware(d / "fw", sample_changer=True, monitor=True), d
    except fw.FirmwareError as e:
        pytest.skip(f"firmware tests skipped: {e}")


@pytest.fixture
def rig_factory(tmp_path, built):
    rigs = []

    def make(fault: str, at: int = 16, *overs: dict, firmware=None) -> Rig:
        rigs.append(Rig(tmp_path, firmware or built, fault, at, *overs))
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
    assert rig.capture(out, resume=True) == 0, capsys.readouterr().err
    s = read(out / "slice.csv")  # the reader refuses a sample recorded twice
    assert sorted(keys(s)) == planned(rig.cfg)  # none lost
    return first


def test_board_reset_mid_reading_stops_safely_and_resumes(rig_factory, capsys, tmp_path):
    rig = rig_factory("reset")
    line = stopped_then_resumed(rig, capsys, tmp_path, "the board restarted")
    assert "BOOT name=gonio-detector" in line and "reset=external" in line


def test_pulled_cable_mid_sweep_stops_safely_and_resumes_on_the_board_plugged_in_again(rig_factory, capsys,
                                                                                      tmp_path):
    rig = rig_factory("unplug")
    stopped_then_resumed(rig, capsys, tmp_path, "is the controller still connected?", before_resume=rig.plug_in)


def test_silent_board_stops_safely_and_resumes(rig_factory, capsys, tmp_path):
    rig = rig_factory("freeze")
    # the operator power-cycles the hung board before resuming
    stopped_then_resumed(rig, capsys, tmp_path, "no valid reply", before_resume=lambda: rig.ask("thaw"))


def test_line_of_noise_is_retried_and_the_capture_completes(rig_factory, capsys, tmp_path):
    rig = rig_factory("noise")
    out = tmp_path / "out"
    assert rig.capture(out) == 0, capsys.readouterr().err
    assert sorted(keys(read(out / "slice.csv"))) == planned(rig.cfg)
    assert "retrying" in (out / "capture.log").read_text()  # the noise did arrive, and was read again


def test_capture_on_the_firmware_agrees_with_the_python_simulator(rig_factory, tmp_path, capsys):
    """The same sweep, the same seed: on the firmware (10-bit ADC, 80 dithered conversions a repeat) and on the
    Python controller (the same noise draws). The samples differ by the ADC's quantisation only: well within a
    sample's std on average, never by many (a wrong gain, pin or timing would be off by far more)."""
    rig = rig_factory("none")
    assert rig.capture(tmp_path / "fw") == 0, capsys.readouterr().err
    fw_slice = read(tmp_path / "fw" / "slice.csv")
    cfg = tmp_path / "python.toml"  # gonio-capture starts gonio-sim serve with its Python controller
    cfg.write_text(tomli_w.dumps({**rig.raw, "bench": {**rig.raw["bench"], "transport": "simulated"}}))
    assert main(["--config", str(cfg), "--out", str(tmp_path / "py"), "--no-progress"]) == 0
    py_slice = read(tmp_path / "py" / "slice.csv")
    assert keys(fw_slice) == keys(py_slice)
    z = (fw_slice.values[:, 0] - py_slice.values[:, 0]) / py_slice.std[:, 0]
    assert np.sqrt(np.mean(z ** 2)) < 1.0 and np.max(np.abs(z)) < 4.0, z
    assert np.any(z != 0)  # the board's own quantisation shows: not a copy of the Python controller's numbers


def test_ratio_readings_divide_a_drifting_source_out_of_a_capture(rig_factory, built_monitor, tmp_path, capsys):
    """A source whose power climbs 10 % an hour of bench time ([simulator].source_drift_per_h) under the board with
    a monitor photodiode: with [detector].monitor = true every sample is the drift-free Python controller's within
    its noise (the monitor's rate during each reading over the white reference's divides the drift out), and the
    slice records the ratio; without it the same board's samples climb with the source, away from them."""
    drift = {"simulator": {"source_drift_per_h": 10.0}}
    cfg = tmp_path / "python.toml"  # the same sweep on the Python controller, the source steady
    cfg.write_text(tomli_w.dumps({**make_raw(PLAN), "bench": {**make_raw(PLAN)["bench"], "transport": "simulated"}}))
    assert main(["--config", str(cfg), "--out", str(tmp_path / "py"), "--no-progress"]) == 0
    steady = read(tmp_path / "py" / "slice.csv")

    def z_against_steady(out, *overs) -> np.ndarray:
        rig = rig_factory("none", 16, drift, *overs, firmware=built_monitor)
        assert rig.capture(tmp_path / out) == 0, capsys.readouterr().err
        s = read(tmp_path / out / "slice.csv")
        assert keys(s) == keys(steady)
        return s, (s.values[:, 0] - steady.values[:, 0]) / steady.std[:, 0]

    ratio, z = z_against_steady("ratio", {"detector": {"monitor": True}})
    assert ratio.meta["calibration"]["monitor_ratio"] is True
    assert ratio.meta["calibration"]["reference_reading"]["monitor_per_s"] > 0
    assert np.sqrt(np.mean(z ** 2)) < 1.5 and np.max(np.abs(z)) < 5.0, z
    plain, z_plain = z_against_steady("plain")
    assert "monitor_ratio" not in plain.meta["calibration"]
    assert np.sqrt(np.mean(z_plain ** 2)) > 3.0 * max(np.sqrt(np.mean(z ** 2)), 0.5), (z_plain, z)
