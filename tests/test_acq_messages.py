"""Issue 49: the messages a user meets. ``--check`` on a PM100 bench names a missing VISA library; a failure
where nothing started (a port, a library) gives no resume advice; a torn last line on resume is one logged line;
after a resume the summary counts what this run measured; stepper benches are not told about servo units; a
bench that cannot switch torque off does not also say it released it; a SIGINT then a SIGTERM is not "SIGTERM
received again"."""

from __future__ import annotations

import pytest

from acquisition import Bench
from acquisition.cli import main
from tests import test_acq_drivers
from tests.test_acq_support import REPO, make_raw, write_config

pty_path = test_acq_drivers.pty_path  # the fixture: a pseudo-terminal whose far end a test can unplug


class _NoVisa:
    """Stand-in of ``pyvisa.ResourceManager`` on a machine without a VISA implementation: pyvisa's documented
    behaviour is that constructing it raises ``ValueError("Could not locate a VISA implementation...")``."""

    def __init__(self, *a, **k):
        raise ValueError("Could not locate a VISA implementation. Install either the IVI binary or pyvisa-py.")


class _Visa:
    """Stand-in of a ``pyvisa.ResourceManager`` that found its VISA library (``close`` is its documented call)."""

    closed = False

    def close(self):
        type(self).closed = True


@pytest.mark.parametrize(("library", "code"), [(_NoVisa, 2), (_Visa, 0)])
def test_check_on_a_pm100_bench_names_a_missing_visa_library(monkeypatch, capsys, library, code):
    import acquisition.devices.external as external

    monkeypatch.setattr(external, "import_pyvisa", lambda: library)
    assert main(["--config", str(REPO / "configs" / "pm100-bench.toml"), "--check"]) == code
    err = capsys.readouterr().err
    if code:
        assert "pyvisa has no VISA library to use" in err and "pyvisa-py" in err and len(err.strip().splitlines()) == 1
    else:
        assert _Visa.closed and "VISA" not in err


def test_a_library_error_where_nothing_started_gives_no_resume_advice(tmp_path):
    raw = make_raw({"detector": {"type": "pm100"}, "bench": {"motion": "serial"}})
    del raw["detector"]["saturation"]
    bench = Bench.from_config(write_config(tmp_path / "pm.toml", raw))
    bench.detector_library = lambda ports: _NoVisa
    r = bench.capture(out=tmp_path / "o", progress=False, handle_signals=False)
    assert r.exit_code == 1 and "pyvisa has no VISA library to use" in r.message, r.message
    assert "Resume with" not in r.message and "--resume" not in r.message
    assert "nothing was moved or captured" in r.message


def test_torque_that_cannot_be_switched_off_is_not_then_reported_released(pty_path, caplog, tmp_path):
    """The Dynamixel bus is gone: the log says to cut the servo power, and not also "motion released"."""
    import logging

    from dynamixel_sdk import PortHandler

    from acquisition import CommError
    from acquisition.config import config_from_dict
    from acquisition.devices.dynamixel import DynamixelAxes

    path, state = pty_path
    bench = Bench.from_config(write_config(tmp_path / "c.toml", make_raw()))
    ax = DynamixelAxes(path, 1000000, bench.cfg.axes, config_from_dict(make_raw(), "t.toml").motion)
    ax.port = PortHandler(path)
    assert ax.port.openPort()
    test_acq_drivers._unplug(state)
    with pytest.raises(CommError):
        ax._txrx("ping", 1, ax.ph.ping)
    bench.motion = ax
    with caplog.at_level(logging.INFO, logger="acquisition"):
        bench.shutdown(park=True)
    text = caplog.text
    assert "cannot switch torque off; cut the servo power" in text
    assert "motion released" not in text
    ax.close()


def test_unit_names_follow_the_bench_in_collision_reasons():
    import numpy as np

    for name, unit in (("grbl-bench", "steps"), ("dynamixel-bench", "servo units")):
        g = Bench.from_config(REPO / "configs" / f"{name}.toml").geometry
        why = [str(w) for w in g.reasons(np.array([(ti, to) for ti in np.arange(5.0, 80.0, 0.7)
                                                   for to in np.arange(-80.0, 0.0, 0.3)])) if w is not None]
        sent = [w for w in why if "at the goals sent" in w]
        assert sent and all(f"in whole {unit})" in w for w in sent), (name, sent[:2])
        assert name == "dynamixel-bench" or not any("servo" in w for w in why)


def test_sigint_then_sigterm_is_not_called_the_same_signal_again(caplog):
    import logging
    import signal

    from acquisition.run.interrupts import SignalGuard

    g = SignalGuard(False)
    g._handler(signal.SIGINT, None)
    g._handler(signal.SIGTERM, None)
    with caplog.at_level(logging.WARNING):
        g.drain()
    assert "SIGTERM received after SIGINT: not waiting for the arms to park" in caplog.text
    assert "received again" not in caplog.text
    g2 = SignalGuard(False)
    g2._handler(signal.SIGINT, None)
    g2._handler(signal.SIGINT, None)
    with caplog.at_level(logging.WARNING):
        g2.drain()
    assert "SIGINT received again" in caplog.text


@pytest.fixture(scope="module")
def small(tmp_path_factory):
    d = tmp_path_factory.mktemp("msg49")
    cfg = write_config(d / "fast.toml", make_raw({"plan": {"theta_i_deg": [30.0, 50.0], "theta_o_step_deg": 10.0}}))
    assert main(["--config", str(cfg), "--out", str(d / "base"), "--no-progress"]) == 0
    return cfg, d / "base"


def test_a_torn_last_line_on_resume_is_one_logged_line_and_the_summary_counts_this_run(small, tmp_path, capsys):
    cfg, base = small
    out = tmp_path / "o"
    out.mkdir()
    (out / "capture.json").write_bytes((base / "capture.json").read_bytes())
    data = (base / "slice.csv").read_bytes()
    cut = data.rstrip(b"\n").rfind(b"\n")
    (out / "slice.csv").write_bytes(data[:cut + 1] + b"\n".join(data[cut + 1:].split(b"\n"))[:20])  # torn last row
    assert main(["--config", str(cfg), "--out", str(out), "--resume", "--no-progress"]) == 0
    err = capsys.readouterr().err
    assert "UserWarning" not in err and "warnings.warn" not in err and "existing = read_slice" not in err, err
    torn = [ln for ln in err.splitlines() if "torn last line" in ln]
    assert len(torn) == 1, err
    assert "torn last line" in (out / "capture.log").read_text()
    assert "captured 1 new sample(s); 28 in" in err
    assert "auto-ranged 1 of this run's 1 point(s) (28 of the capture's 28)" in err, err


def test_a_simulator_faster_than_real_time_explains_why_the_capture_outruns_the_estimate(tmp_path, capsys):
    """At time_scale K > 1 the software's own wall time counts K times over as bench time (issue 49: a Dynamixel
    plan estimated 46.0 s took 57.6 s); the summary says so, and not at K = 0 (time jumps: the model is exact)."""
    plan = {"plan": {"theta_i_deg": [30.0], "theta_o_step_deg": 35.0}}
    for k, note in ((10.0, True), (0.0, False)):
        cfg = write_config(tmp_path / f"k{k:g}.toml", make_raw(plan, {"simulator": {"time_scale": k}}))
        assert main(["--config", str(cfg), "--out", str(tmp_path / f"o{k:g}"), "--no-progress"]) == 0
        err = capsys.readouterr().err
        assert ("at [simulator].time_scale = 10 the software's own wall time" in err) is note, err
