"""Text protocol through a pty with the real serial.Serial (stepper bench), and in-process via sim://."""

from __future__ import annotations

import time

import pytest
import serial
import tomli_w

import simulator  # noqa: F401 - registers sim://
from simulator.ports.transports import register_bench, unregister_bench
from tests.helpers import units as steps  # the simulated stepper counts the same units


class Link:
    def __init__(self, ser: serial.SerialBase) -> None:
        self.ser = ser

    def cmd(self, line: str, timeout: float = 5.0) -> list[str]:
        self.ser.write((line + "\n").encode())
        out: list[str] = []
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            raw = self.ser.readline()
            if not raw:
                continue
            ln = raw.decode().strip()
            out.append(ln)
            if ln == "ok" or ln.startswith("error:"):
                return out
        raise AssertionError(f"no final line for {line!r}: {out}")

    def fields(self, line: str) -> dict[str, str]:
        lines = self.cmd(line)
        assert lines[-1] == "ok", lines
        return dict(f.split("=", 1) for f in lines[0].split()[1:])


@pytest.fixture(scope="module")
def stepper_link(tmp_path_factory, serve_process, base_config_dict, deep_merge):
    raw = deep_merge(base_config_dict, {"bench": {"motion": "serial"}})
    cfg = tmp_path_factory.mktemp("serial") / "stepper.toml"
    cfg.write_text(tomli_w.dumps(raw))
    sp = serve_process(cfg)
    assert sp.ports["dynamixel"] is None
    ser = serial.Serial(sp.ports["serial"], 115200, timeout=0.5)
    yield Link(ser)
    ser.close()
    assert sp.stop() == 0


def wait_idle(link: Link) -> dict[str, str]:
    for _ in range(200):
        st = link.fields("STATUS?")
        if st["state"] != "Moving":
            return st
    raise AssertionError("axes never became idle")


def test_identity_and_status(stepper_link):
    info = stepper_link.fields("ID?")
    assert info["motion"] == "serial" and info["axes"] == "L,D" and info["detector"] == "photodiode"
    st = stepper_link.fields("STATUS?")
    assert st["state"] == "Idle" and int(st["L"]) == steps(0) and int(st["D"]) == steps(45)
    assert stepper_link.cmd("?")[-1] == "ok"


def test_move_status_read_dark(stepper_link):
    assert stepper_link.cmd(f"MOVE L{steps(30)} D{steps(-10)}") == ["ok"]
    t0 = float(stepper_link.fields("TIME?")["t"])
    st = wait_idle(stepper_link)
    assert st["state"] == "Idle" and int(st["L"]) == steps(30) and int(st["D"]) == steps(-10)
    assert float(st["t"]) > t0  # the move took simulated time
    r = stepper_link.fields("READ 4")
    assert r["n"] == "4" and len(r["values"].split(",")) == 4
    d = stepper_link.fields("DARK 4")
    assert float(d["mean"]) < float(r["mean"])
    assert stepper_link.fields("DETECTOR?")["type"] == "photodiode"


def test_errors(stepper_link):
    assert stepper_link.cmd("FROB") == ["error:1"]
    assert stepper_link.cmd("MOVE Lxyz") == ["error:2"]
    assert stepper_link.cmd("MOVE Q100") == ["error:10"]
    assert stepper_link.cmd(f"MOVE L{steps(95)}") == ["error:3"]     # light soft limit is 85 deg
    assert stepper_link.cmd("READ 0") == ["error:2"]
    assert stepper_link.cmd("SAMPLE NOPE") == ["error:2"]


def test_collision_alarm_and_reset(stepper_link):
    wait_idle(stepper_link)
    assert stepper_link.cmd(f"MOVE L{steps(20)} D{steps(30)}") == ["ok"]
    wait_idle(stepper_link)
    assert stepper_link.cmd(f"MOVE D{steps(-18)}") == ["ALARM:20", "error:20"]  # |20 - 18| < 6
    st = stepper_link.fields("STATUS?")
    assert st["state"] == "Alarm" and st["alarm"] == "20" and int(st["D"]) == steps(30)
    assert stepper_link.cmd(f"MOVE D{steps(40)}") == ["error:9"]
    assert stepper_link.cmd("RESET") == ["ok"]
    assert stepper_link.cmd(f"MOVE D{steps(40)}") == ["ok"]
    assert stepper_link.cmd("HOME") == ["error:11"]  # still moving
    wait_idle(stepper_link)
    assert stepper_link.cmd("HOME") == ["ok"]
    st = wait_idle(stepper_link)
    assert int(st["L"]) == steps(0) and int(st["D"]) == steps(45) and st["homed"] == "1"


def test_sim_url_in_process(base_config_dict):
    from simulator.bench import VirtualBench
    from simulator.config import config_from_dict

    bench = VirtualBench(config_from_dict(base_config_dict))
    register_bench("unit-url", bench)
    try:
        s = serial.serial_for_url("sim://unit-url/serial", timeout=1)
        link = Link(s)
        assert link.fields("ID?")["motion"] == "none"  # Dynamixel bench: detector only
        assert link.cmd("MOVE L100") == ["error:10"]
        link.cmd("DWELL 2.5")
        assert float(link.fields("TIME?")["t"]) == pytest.approx(2.5)
        s.close()
        with pytest.raises(serial.SerialException):
            serial.serial_for_url("sim://no-such-bench/serial")
    finally:
        unregister_bench("unit-url")


def test_homing_required(config_dict):
    from simulator.bench import VirtualBench
    from simulator.config import config_from_dict

    b = VirtualBench(config_from_dict(config_dict({"bench": {"motion": "serial"},
                                                   "simulator": {"homing_required": True}})))
    assert b.process("serial", f"MOVE L{steps(10)}\n".encode()) == b"error:8\n"
    assert b.process("serial", b"HOME\n") == b"ok\n"
    assert b.process("serial", b"STATUS?\n").decode().split()[1] == "state=Idle"
    assert b.process("serial", f"MOVE L{steps(10)}\n".encode()) == b"ok\n"


def test_single_number_arguments(config_dict):
    """DWELL, INT and GAIN take exactly one number within their range, else error:2 and nothing changes."""
    from simulator.bench import VirtualBench
    from simulator.config import config_from_dict

    b = VirtualBench(config_from_dict(config_dict()))
    for line in ("DWELL", "DWELL x", "DWELL -1", "DWELL 3601", "DWELL 1 2", "DWELL nan", "INT", "INT 1e-6",
                 "INT 11", "INT 0.01 0.02", "GAIN 0.001", "GAIN 3", "GAIN 1 1", "GAIN inf"):
        assert b.process("serial", f"{line}\n".encode()) == b"error:2\n", line
    assert b.sim_time() == 0.0
    assert b.process("serial", b"INT?\n") == b"INT t_int=0.01\nok\n"
    for line in ("DWELL 0", "DWELL 2.5", "INT 1e-5", "INT 10", "GAIN 10000", "GAIN 1000"):
        assert b.process("serial", f"{line}\n".encode()) == b"ok\n", line
    assert b.sim_time() == pytest.approx(2.5)
    assert b.process("serial", b"INT?\n") == b"INT t_int=10\nok\n"
    assert b.process("serial", b"GAIN?\n") == b"GAIN gain=1000\nok\n"
    assert b.physics.detector.gain == 1000.0
    raw = config_dict()
    del raw["detector"]["gains"]  # an amplifier without a list of gains: any gain in 0.01..1000
    b = VirtualBench(config_from_dict(raw))
    for line, reply in (("GAIN 0.001", b"error:2\n"), ("GAIN 1001", b"error:2\n"), ("GAIN 0.01", b"ok\n"),
                        ("GAIN 3", b"ok\n")):
        assert b.process("serial", f"{line}\n".encode()) == reply, line
