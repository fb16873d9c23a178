"""Issue 49: every written table's report and console say when its samples cannot support it (too few samples,
a chosen method judged on one held-out fold, fitted parameters at their bounds), name values impossibly far below
zero for their uncertainty, and a refusal of auto names each method's real reason (never ``None``)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reconstruction import cli
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice, below_zero
from reconstruction.formats.slicefile import write_slice
from reconstruction.report.summary import parameters_at_bounds
from reconstruction.synthetic import synthetic_slice

MAT = Material.from_dict({"name": "grey", "lobes": [{"type": "lambert", "albedo": 0.3},
                                                    {"type": "ggx", "alpha": 0.2, "specular": 0.3}]})


def _write(path, s: Slice, std=None):
    n = len(s)
    write_slice(path, Slice(s.theta_i_deg, s.theta_o_deg, s.values, s.channels,
                            0.01 * np.abs(s.values) + 1e-6 if std is None else std, np.full(n, 4),
                            1.7e9 + np.arange(n), meta={"material": "grey"}))
    return path


def _run(capsys, *argv) -> tuple[int, str]:
    code = cli.main([str(a) for a in argv])
    return code, capsys.readouterr().err


@pytest.fixture(scope="module")
def three(tmp_path_factory):
    s = synthetic_slice(MAT, (30.0,), step_deg=5.0)
    s = s.take(np.isin(s.theta_o_deg, [-70.0, -40.0, 0.0]))  # the three samples of a 30 deg slice
    assert len(s) == 3
    return _write(tmp_path_factory.mktemp("few") / "three.csv", s)


@pytest.mark.parametrize("method", ["fit", "revolve", "bivariate", "auto"])
def test_a_table_from_three_samples_says_they_cannot_support_it(three, tmp_path, capsys, method):
    report = tmp_path / "r.json"
    code, err = _run(capsys, three, "--method", method, "--out", tmp_path / "m.binary", "--report", report)
    assert code == 0, err
    warned = [ln for ln in err.splitlines() if "warning:" in ln]
    assert any("only 3 sample(s) at 1 incidence(s): too few to support" in ln for ln in warned), err
    assert "checks passed, but see the" in err
    rep = json.loads(report.read_text())
    assert any("too few to support" in w for w in rep["warnings"])


def test_a_wide_slice_has_no_such_warning(tmp_path, capsys):
    src = _write(tmp_path / "wide.csv", synthetic_slice(MAT, (20.0, 40.0, 60.0), step_deg=5.0))
    report = tmp_path / "r.json"
    code, err = _run(capsys, src, "--method", "fit", "--out", tmp_path / "m.binary", "--report", report)
    assert code == 0 and "warning" not in err and "warnings" not in json.loads(report.read_text()), err


def test_values_impossibly_below_zero_for_their_std_are_named(tmp_path, capsys):
    s = synthetic_slice(MAT, (20.0, 40.0, 60.0), step_deg=5.0)
    std = 0.01 * np.abs(s.values) + 1e-6
    k = int(np.flatnonzero((s.theta_i_deg == 40.0) & (s.theta_o_deg == 10.0))[0])
    s.values[k] = -0.5
    std[k] = 7e-5
    src = _write(tmp_path / "neg.csv", s, std)
    report = tmp_path / "r.json"
    code, err = _run(capsys, src, "--method", "fit", "--out", tmp_path / "m.binary", "--report", report)
    assert code == 0
    assert "1 sample(s) below zero far beyond their uncertainty" in err and "(40, 10) f_r -0.5 +- 7e-05" in err, err
    rep = json.loads(report.read_text())
    assert "(40, 10)" in rep["coverage"]["below_zero"] and any("below zero" in w for w in rep["warnings"])


def test_below_zero_is_judged_by_the_uncertainty_not_the_sign():
    v = np.array([[-0.5], [-0.5], [-1e-4], [0.2], [-3e-4]])
    sd = np.array([[7e-5], [0.2], [1e-4], [1e-5], [1e-5]])
    # -0.5 +- 7e-5: 7000 sigma; -0.5 +- 0.2: 2.5 sigma (noise); -1e-4 within the floor; -3e-4 is 30 sigma but
    # under the floor of 0.1 % of the largest value (0.5)
    assert below_zero(v, sd).tolist() == [True, False, False, False, False]


def test_parameters_at_their_bounds_are_named():
    assert parameters_at_bounds([{"type": "ggx", "alpha": 1.5, "specular": [0.1]}]) == [
        "ggx alpha 1.5 (its upper bound)"]
    assert parameters_at_bounds([{"type": "ggx", "alpha": 0.2}, {"type": "lambert", "albedo": [0.3]}]) == []


def test_autos_refusal_names_each_methods_real_reason(tmp_path, capsys):
    """Three samples around the mirror direction: no method can be held out; the refusal says why (was
    ``fit: None; microfacet: None; ...``)."""
    s = synthetic_slice(MAT, (30.0,), step_deg=1.0)
    s = s.take(np.isin(s.theta_o_deg, [29.0, 30.0, 31.0]))
    src = _write(tmp_path / "mirror.csv", s)
    code, err = _run(capsys, src, "--method", "auto", "--out", tmp_path / "m.binary")
    assert code != 0 and "None" not in err, err
    assert "no sample could be held out to judge it" in err and "fit" in err and "bivariate" in err
