"""Issue 49, item 4: a white reference taken through the operator prompt (no sample changer) is checked before
the sweep. The new user's case: Enter pressed without mounting the panel, so the "reference" is the sample and
every f_r comes out 2-3 times too high with a normal log; now a warning names the doubtful reference before the
first point. The rule itself (against the dark, the sample in the same geometry, the previous reference) is
checked on readings."""

from __future__ import annotations

import re

import numpy as np

from acquisition import Bench
from acquisition.calibration import Reading
from acquisition.plans.reference import reference_doubts
from tests.test_acq_support import REPO, make_raw, write_config


def _reading(mean: float, std: float = 1.0, n: int = 32) -> Reading:
    return Reading(np.array([mean]), np.array([std]), n)


def test_the_rule_against_the_dark_the_sample_and_the_previous_reference():
    dark, ref = _reading(100.0), _reading(30000.0, 20.0)
    assert reference_doubts(ref, dark, _reading(9000.0), 0.99, _reading(29000.0)) == []
    assert "less than 10 times its uncertainty" in reference_doubts(_reading(102.0), dark)[0]
    said = reference_doubts(ref, dark, _reading(29990.0), 0.99)
    assert len(said) == 1 and "the sample in the same geometry gives 100% of its signal" in said[0]
    assert "differs from the previous reference's" in reference_doubts(ref, dark, previous=_reading(20000.0))[0]


def _capture(tmp_path, name: str, swap) -> tuple[str, np.ndarray]:
    cfg = write_config(tmp_path / f"{name}.toml", make_raw({"plan": {"theta_o_step_deg": 20.0}}))
    bench = Bench.from_config(cfg)
    bench.open()
    try:
        det = bench.detector
        det.has_sample_changer = False  # a board built without SAMPLE_CHANGER=1: the operator swaps by hand
        det.manual_swap = swap(bench)
        r = bench.capture(out=tmp_path / name, progress=False, handle_signals=False)
        assert r.ok, r.message
    finally:
        bench.close()
    from tests.test_acq_support import read

    return (tmp_path / name / "capture.log").read_text(), read(tmp_path / name / "slice.csv").values[:, 0]


def test_enter_pressed_without_mounting_the_reference_is_named_before_the_sweep(tmp_path):
    log, f_wrong = _capture(tmp_path, "nothing-mounted", lambda bench: lambda which: None)
    m = re.search(r"white reference doubtful: the sample in the same geometry gives (\d+)% of its signal", log)
    assert m and int(m.group(1)) >= 90, log
    assert log.index("white reference doubtful") < log.index("point(s) to measure")  # before the sweep
    # the operator who does mount it (here: the changer moved by hand through the board's own command)
    log_ok, f_ok = _capture(tmp_path, "mounted", lambda bench: lambda which: bench.link.command(f"SAMPLE {which}"))
    assert "doubtful" not in log_ok and "the sample at the reference geometry" in log_ok
    assert np.median(f_wrong / f_ok) > 1.5  # what the warning is about: every f_r too high by the same factor


def test_a_bench_with_a_changer_reads_nothing_more(tmp_path):
    cfg = write_config(tmp_path / "c.toml", make_raw({"plan": {"theta_o_step_deg": 20.0}}))
    r = Bench.from_config(cfg).capture(out=tmp_path / "o", progress=False, handle_signals=False)
    assert r.ok
    log = (tmp_path / "o" / "capture.log").read_text()
    assert "the sample at the reference geometry" not in log and "doubtful" not in log


def test_the_readme_firmware_line_builds_what_the_demo_needs():
    """The demo calibrates against a white reference through the board's sample changer (SAMPLE REF): the
    README's build line must build it in (the Makefile's default has none)."""
    makefile = (REPO / "firmware" / "detector" / "Makefile").read_text()
    default = re.search(r"^SAMPLE_CHANGER \?= (\d)", makefile, re.M)
    assert default is not None
    readme = (REPO / "README.md").read_text()
    lines = re.findall(r"`(make -C firmware/detector[^`]*)`", readme)
    assert lines, "the README names no firmware build line"
    for line in lines:
        flag = re.search(r"SAMPLE_CHANGER=(\d)", line)
        assert (flag.group(1) if flag else default.group(1)) == "1", line
    assert 'mode = "relative"' in (REPO / "configs" / "simulated.toml").read_text()  # the demo needs the reference
