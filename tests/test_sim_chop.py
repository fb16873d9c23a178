"""gonio-sim's own serial controller under room light ([simulator].ambient): a plain READ carries it, CHOP ON
(as the detector board's firmware does it, docs/serial-protocol.md) subtracts as long a reading with the source
off, so the chopped reading is the dark room's READ - DARK within noise; and gonio-capture's [detector].chop
captures the dark room's slice under room light."""

from __future__ import annotations

import numpy as np

from acquisition.cli import main
from simulator.bench import VirtualBench
from simulator.config import config_from_dict
from tests.test_acq_support import make_raw, read, write_config


def fields(bench: VirtualBench, cmd: str) -> dict[str, str]:
    lines = bench.process("serial", (cmd + "\n").encode()).decode().splitlines()
    assert lines[-1] == "ok", lines
    return dict(f.split("=", 1) for f in lines[0].split()[1:])


def values(f: dict[str, str]) -> np.ndarray:
    return np.array([float(v) for v in f["values"].split(",")])


def test_chopped_reads_under_room_light_equal_the_dark_rooms():
    bench = VirtualBench(config_from_dict(make_raw({"simulator": {"read_noise": 5.0}})))
    assert bench.process("serial", b"GAIN 100\n") == b"ok\n"
    lit, dark = values(fields(bench, "READ 32")), values(fields(bench, "DARK 32"))
    signal = lit.mean() - dark.mean()
    err = np.hypot(lit.std(ddof=1), dark.std(ddof=1)) / np.sqrt(32)
    bench.physics.ambient = 10 * signal / 100  # room light at 10 x the signal (counts at gain 1)
    plain = values(fields(bench, "READ 32"))
    assert plain.mean() - lit.mean() > 8 * signal  # off by the room light
    assert bench.process("serial", b"CHOP ON\n") == b"ok\n"
    assert fields(bench, "CHOP?") == {"chop": "ON", "half": "0.01"}
    t0 = float(fields(bench, "TIME?")["t"])
    chopped = values(fields(bench, "READ 32"))
    assert float(fields(bench, "TIME?")["t"]) - t0 >= 2 * 32 * 0.01  # the off halves take their time
    c_err = chopped.std(ddof=1) / np.sqrt(32)
    assert abs(chopped.mean() - signal) < 3 * np.hypot(err, c_err), (chopped.mean(), signal)
    residual = values(fields(bench, "DARK 32"))  # the source off in both halves: nothing left
    assert abs(residual.mean()) < 3 * residual.std(ddof=1) / np.sqrt(32) + 1
    assert bench.process("serial", b"CHOP MAYBE\n") == b"error:2\n"


def test_a_capture_with_chop_under_room_light_is_the_dark_rooms(tmp_path):
    """Room light that the most sensitive gain still holds (3 counts at gain 1: 30,000 at gain 10,000; more would
    saturate the dark there and stop the capture, as on a real bench); the chopped capture's samples agree with the
    dark room's, and its dark is zero within noise (no offset, no room light)."""
    plan = {"plan": {"theta_i_deg": [30.0], "theta_o_min_deg": -20.0, "theta_o_max_deg": 60.0,
                     "theta_o_step_deg": 20.0, "repeats": 16}}
    runs = {}
    for name, over in (("dark-room", {}), ("chopped", {"simulator": {"ambient": 3.0}, "detector": {"chop": True}})):
        out = tmp_path / name
        assert main(["--config", str(write_config(tmp_path / f"{name}.toml", make_raw(plan, over))), "--out",
                     str(out), "--no-progress"]) == 0
        runs[name] = read(out / "slice.csv")
    base, chop = runs["dark-room"], runs["chopped"]
    z = (chop.values - base.values) / np.hypot(chop.std, base.std)
    assert np.all(np.abs(z) < 4), z.ravel()
    dark = chop.meta["calibration"]["dark"]
    assert abs(dark["mean"][0]) < 3 * dark["std"][0] / np.sqrt(dark["n"]) + 1  # offsets and room light cancel
    assert base.meta["calibration"]["dark"]["mean"][0] > 2000  # the dark room's offset at gain 10,000
