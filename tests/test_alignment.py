"""gonio-align: the alignment's geometry and fit (reconstruction.instrument.alignment), the simulator's
[simulator.misalignment], and the command recovering an injected misalignment on the simulated bench."""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np
import pytest
import tomllib
from scipy.optimize import brentq

from reconstruction.instrument.alignment import (
    AlignmentError,
    combine,
    fit_diffuse_zero,
    fit_specular,
    peak_centre,
    specular_peak_deg,
    true_angles,
    zero_offset_for,
)

REPO = Path(__file__).resolve().parents[1]
R = 70.0


def _specular(ti: float, a: float, b: float, t: float, h: float) -> float:
    """The detector arm's reading at the specular peak, solved from the true geometry."""
    return brentq(lambda to: float(np.subtract(*true_angles(ti, to, a, b, t, h, R)[::-1])), ti - 10, ti + 10)


def test_true_angles_are_the_readings_on_an_aligned_bench_and_follow_each_offset():
    ti, to = true_angles([20.0, 45.0], [-30.0, 60.0])
    assert np.allclose(ti, [20, 45]) and np.allclose(to, [-30, 60])
    ti, to = true_angles(30.0, 40.0, light_zero_deg=0.3, detector_zero_deg=-0.2, tilt_deg=0.1)
    assert ti == pytest.approx(30.4) and to == pytest.approx(39.7)


def test_the_specular_model_is_the_geometry_solved():
    a, b, t, h = 0.3, -0.2, 0.15, 0.8
    for ti in (20.0, 35.0, 50.0, 65.0):
        assert specular_peak_deg(ti, a - b + 2 * t, h, R, a + t) == pytest.approx(_specular(ti, a, b, t, h), abs=1e-9)
    # the reflected ray misses the axis by 2 h sin(theta_i): the peak moves by about that over R
    assert specular_peak_deg(60.0, 0.0, 1.0, R) - 60.0 == pytest.approx(-np.degrees(2 * np.sin(np.radians(60)) / R),
                                                                        rel=0.02)


def test_a_sweep_of_specular_peaks_cannot_tell_the_arms_from_each_other_or_from_the_tilt():
    """What the guide states: turning both arms by e, or trading t against a, leaves every peak where it was."""
    ti = (20.0, 35.0, 50.0, 65.0)
    base = [_specular(x, 0.3, -0.2, 0.15, 0.0) for x in ti]
    both = [_specular(x, 0.3 + 0.4, -0.2 + 0.4, 0.15, 0.0) for x in ti]
    traded = [_specular(x, 0.3 - 0.2, -0.2, 0.15 + 0.1, 0.0) for x in ti]
    assert np.allclose(base, both, atol=1e-9) and np.allclose(base, traded, atol=1e-9)
    # ... while the surface offset grows with sin(theta_i) and separates from the constant
    fit = fit_specular(ti, [_specular(x, 0.3, -0.2, 0.15, 0.5) for x in ti], R, alpha_deg=0.45)
    assert fit.c_deg == pytest.approx(0.8, abs=1e-6) and fit.surface_offset_mm == pytest.approx(0.5, abs=1e-5)


def test_combine_separates_what_the_extra_measurements_determine():
    a, b, t = 0.3, -0.2, 0.15
    first = fit_specular([20, 40, 60], [20 + a - b + 2 * t, 40 + a - b + 2 * t, 60 + a - b + 2 * t], R)
    turned = fit_specular([20, 40, 60], [20 + a - b - 2 * t, 40 + a - b - 2 * t, 60 + a - b - 2 * t], R)
    only = combine(first)
    assert only.detector_zero_deg is None and only.light_zero_deg is None and only.tilt_deg is None
    ref = combine(first, b)
    assert ref.light_zero_deg is None and ref.light_plus_2tilt_deg == pytest.approx(a + 2 * t)
    full = combine(first, b, turned)
    assert (full.light_zero_deg, full.detector_zero_deg, full.tilt_deg) == pytest.approx((a, b, t))


def test_peak_centre_finds_a_flat_top_and_says_when_the_peak_runs_off_the_sweep():
    x = np.arange(27.5, 32.5, 0.088)
    d = np.abs(x - 30.17)
    y = np.clip((1.3 - d) / 0.5, 0.0, 1.0) * 1e5 + 3.0
    assert peak_centre(x, y) == pytest.approx(30.17, abs=0.005)
    with pytest.raises(AlignmentError, match="larger than the sweep"):
        peak_centre(x, np.clip((1.3 - np.abs(x - 32.0)) / 0.5, 0.0, 1.0))
    with pytest.raises(AlignmentError, match="no specular peak"):
        peak_centre(x, np.full_like(x, 5.0))


def test_the_fit_refuses_peaks_it_cannot_explain():
    ti = np.array([20.0, 35.0, 50.0, 65.0])
    with pytest.raises(AlignmentError, match="beyond what this fit models"):
        fit_specular(ti, ti + 0.5 + 0.02 * (ti - 40) ** 2 / 10, R)   # a curved mirror's peaks
    with pytest.raises(AlignmentError, match="3 incidences or more"):
        fit_specular([30.0, 60.0], [30.2, 60.2], R)


def test_the_white_reference_sweep_gives_the_detector_arm_zero():
    to = np.concatenate([-np.arange(15, 80, 5.0), np.arange(15, 80, 5.0)])
    b = -0.23
    lam = np.cos(np.radians(to + b))
    assert fit_diffuse_zero(to, lam)[0] == pytest.approx(b, abs=1e-6)
    u = np.radians(to + b)  # a diffuser that is not Lambertian, symmetric about its normal
    assert fit_diffuse_zero(to, np.cos(u) * (1 - 0.1 * u * u))[0] == pytest.approx(b, abs=1e-6)


def test_zero_offset_for_corrects_the_arm():
    # the arm stood 0.3 deg past its readings: the units of a reading theta must be those of theta - 0.3 before
    new = zero_offset_for(2048, -1, 4096 / 360, 0.3)
    assert new + -1 * 4096 / 360 * 10.0 == pytest.approx(2048 + -1 * 4096 / 360 * (10.0 - 0.3))


def test_the_misalignment_table_is_validated(tmp_path):
    from simulator.config import ConfigError, load_config

    text = (REPO / "configs" / "mirror-misaligned.toml").read_text()
    cfg = load_config(REPO / "configs" / "mirror-misaligned.toml")
    m = cfg.sim.misalignment
    assert (m.light_zero_deg, m.detector_zero_deg, m.sample_tilt_deg, m.surface_offset_mm) == (0.3, -0.2, 0.15, 0.3)
    assert cfg.bench.detector_distance_mm == 70.0
    for what in ("sample_tilt = 0.15", "sample_tilt_deg = 45.0"):
        p = tmp_path / "bad.toml"
        p.write_text(text.replace("sample_tilt_deg = 0.15", what))
        with pytest.raises(ConfigError, match=r"\[simulator.misalignment\]"):
            load_config(p)


def test_the_simulator_reads_at_the_true_angles():
    from simulator.config import load_config
    from simulator.world.physics import BenchPhysics

    cfg = load_config(REPO / "configs" / "mirror-misaligned.toml")
    ph = BenchPhysics(cfg, np.random.default_rng(0))
    ti, to = ph.true_angles(np.array([40.0]), np.array([40.0]))
    m = cfg.sim.misalignment
    want = true_angles(40.0, 40.0, m.light_zero_deg, m.detector_zero_deg, m.sample_tilt_deg, m.surface_offset_mm, R)
    assert np.allclose([ti[0], to[0]], [float(want[0]), float(want[1])])
    ph.sample = "REF"  # the white reference lies flat: only the arms' offsets and the surface offset
    ti, _ = ph.true_angles(np.array([0.0]), np.array([30.0]))
    assert ti[0] == pytest.approx(m.light_zero_deg, abs=1e-9)


def _align(*args: str) -> tuple[int, str, str]:
    import contextlib
    import io

    from acquisition.align import main

    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        status = main(list(args))
    return status, out.getvalue(), err.getvalue()


@pytest.mark.slow
def test_gonio_align_recovers_the_injected_misalignment(tmp_path):
    """configs/mirror-misaligned*.toml: a = 0.30, b = -0.20, t = 0.15 deg, h = 0.30 mm, found to within 0.05 deg
    (offsets), 0.1 deg (tilt) and 0.05 mm; --write puts the printed zero offsets into the bench file."""
    first = tmp_path / "align1.json"
    status, out, err = _align("--config", str(REPO / "configs" / "mirror-misaligned.toml"), "--save", str(first),
                              "--json")
    assert status == 0, err
    one = json.loads(out)
    assert one["detector_zero_deg"] == pytest.approx(-0.20, abs=0.05)
    assert one["light_plus_2tilt_deg"] == pytest.approx(0.30 + 2 * 0.15, abs=0.05)
    assert one["light_zero_deg"] is None and one["tilt_deg"] is None   # not determined without the turn
    cfg = tmp_path / "bench.toml"
    cfg.write_text((REPO / "configs" / "mirror-misaligned-turned.toml").read_text())
    status, out, err = _align("--config", str(cfg), "--turned", str(first), "--json", "--write")
    assert status == 0, err
    r = json.loads(out)
    assert r["light_zero_deg"] == pytest.approx(0.30, abs=0.05)
    assert r["detector_zero_deg"] == pytest.approx(-0.20, abs=0.05)
    assert r["tilt_deg"] == pytest.approx(0.15, abs=0.1)
    assert r["surface_offset_mm"] == pytest.approx(0.30, abs=0.05)
    axes = tomllib.loads(cfg.read_text())["axes"]
    assert axes["light"]["zero_offset"] == pytest.approx(r["zero_offset"]["light"])
    assert axes["detector"]["zero_offset"] == pytest.approx(r["zero_offset"]["detector"])
    assert axes["light"]["zero_offset"] == pytest.approx(2048 - 4096 / 360 * r["light_zero_deg"])
    assert "wrote zero_offset of detector, light" in err


@pytest.mark.slow
def test_gonio_align_says_when_the_misalignment_is_beyond_its_sweep(tmp_path):
    cfg = tmp_path / "bench.toml"
    cfg.write_text((REPO / "configs" / "mirror-misaligned.toml").read_text()
                   .replace("detector_zero_deg = -0.20", "detector_zero_deg = -4.0"))
    status, out, err = _align("--config", str(cfg), "--no-reference", "--incidences", "20,40,60")
    assert status == 1 and out == ""
    assert re.search(r"theta_i = 20\.0\d deg: the specular peak runs past the sweep's upper end", err), err
    assert "widen --window" in err
    status, out, err = _align("--config", str(cfg), "--no-reference", "--incidences", "20,40,60", "--window", "6")
    assert status == 0, err
    assert "a - b + 2t = +4.5" in out and "no white reference sweep" in out


def test_gonio_align_refuses_bad_arguments_before_moving(tmp_path):
    status, _, err = _align("--config", str(REPO / "configs" / "mirror-misaligned.toml"), "--incidences", "a,b")
    assert status == 2 and "--incidences" in err
    status, _, err = _align("--config", str(tmp_path / "none.toml"))
    assert status == 2 and "no such file" in err and "nothing was moved" in err
    status, _, err = _align("--config", str(REPO / "configs" / "mirror-misaligned.toml"), "--turned",
                            str(tmp_path / "none.json"))
    assert status == 2 and "--turned" in err


def test_gonio_capture_align_runs_gonio_align(tmp_path, capsys):
    from acquisition.cli import main

    assert main(["--config", str(tmp_path / "none.toml"), "--align"]) == 2
    err = capsys.readouterr().err
    assert err.startswith("gonio-align: ") and "no such file" in err


def test_the_guides_gonio_align_lines_parse():
    import shlex

    from acquisition.align import build_parser

    text = (REPO / "docs" / "build-a-bench.md").read_text()
    lines = [ln.split("#")[0] for b in re.findall(r"```sh\n(.*?)```", text, flags=re.S) for ln in b.splitlines()
             if ln.startswith("gonio-align")]
    lines += [ln[2:] for ln in text.splitlines() if ln.startswith("$ gonio-align")]
    assert len(lines) >= 4
    for ln in lines:
        build_parser().parse_args(shlex.split(ln)[1:])
