"""Guard rails where the tool answered wrongly in silence (issue 41): radians read as degrees, samples too
narrow to tabulate from, a choice that predicts its held-out samples badly."""

import numpy as np
import pytest

from reconstruction import cli
from reconstruction.core.slicedata import Slice
from reconstruction.formats.inputs import InputError, load_inputs
from reconstruction.formats.slicefile import write_slice
from reconstruction.report.summary import LARGE_HELD_OUT, guard_warnings


def _angles():
    to = np.arange(-80.0, 81.0, 5.0)
    to = to[np.abs(to + 30.0) > 6.0]
    return np.full(to.size, 30.0), to, (0.06 + 2.0 * np.exp(-((to - 30.0) / 8.0) ** 2))[:, None]


def _table(tmp_path, ti, to, v, name="t.csv"):
    p = tmp_path / name
    p.write_text("incidence,outgoing,value\n" + "".join(f"{a:.6f},{b:.6f},{c:.6f}\n"
                                                         for a, b, c in zip(ti, to, v[:, 0], strict=True)))
    return p


def test_radians_in_a_generic_table_are_refused_naming_the_column(tmp_path, capsys):
    ti, to, v = _angles()
    p = _table(tmp_path, np.radians(ti), np.radians(to), v)
    code = cli.main([str(p), "--quantity", "brdf", "--out", str(tmp_path / "m.binary"), "--quiet"])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "Traceback" not in err
    assert "t.csv: column outgoing: every angle lies within +-1.6" in err and "--angles-in radians" in err
    assert not (tmp_path / "m.binary").exists()


def test_radians_in_a_slice_file_are_refused_and_read_with_angles_in_radians(tmp_path):
    ti, to, v = _angles()
    p = tmp_path / "s.csv"
    write_slice(p, Slice(np.radians(ti), np.radians(to), v, ["value"], meta={"quantity": "brdf"}))
    with pytest.raises(InputError, match=r"s\.csv: column theta_o_deg: every angle lies within \+-1\.6.*--angles-in "
                                         r"radians"):
        load_inputs([p])
    s = load_inputs([p], angles_in="radians").slice
    np.testing.assert_allclose(np.sort(s.theta_o_deg), np.sort(to), atol=1e-9)
    q = _table(tmp_path, np.radians(ti), np.radians(to), v)
    s = load_inputs([q], quantity="brdf", angles_in="radians").slice
    np.testing.assert_allclose(np.sort(s.theta_o_deg), np.sort(to), atol=1e-4)  # 6 decimals of radians
    with pytest.raises(InputError, match=r"t\.csv: column incidence: 30 is not an angle in radians"):
        load_inputs([_table(tmp_path, ti, to, v)], quantity="brdf", angles_in="radians")


def test_narrow_samples_are_warned_of(tmp_path, capsys):
    to = np.arange(24.0, 37.0, 1.0)
    p = _table(tmp_path, np.full(to.size, 30.0), to, (0.1 + np.exp(-((to - 30.0) / 3.0) ** 2))[:, None])
    code = cli.main([str(p), "--quantity", "brdf", "--method", "fit", "--out", str(tmp_path / "m.binary"),
                     "--quiet"])
    err = capsys.readouterr().err
    assert code == 0
    assert "warning: " in err and "the samples span only 12 deg of theta_o" in err


def test_a_choice_that_predicts_badly_is_warned_of():
    cov = {"incidences": [{"theta_o_min_deg": -80.0, "theta_o_max_deg": 80.0}], "half_diff_bins_with_samples": 30,
           "half_diff_bins_total": 8100}
    cv = {"chosen_label": "fit", "scores": [{"label": "microfacet", "held_out_relative_rmse_cos": 0.05},
                                            {"label": "fit", "held_out_relative_rmse_cos": 0.79}]}
    said = guard_warnings(cov, cv, "x.csv")
    assert len(said) == 1 and "fit, predicts the samples it did not see to 79%" in said[0]
    cv["scores"][1]["held_out_relative_rmse_cos"] = LARGE_HELD_OUT / 2
    assert guard_warnings(cov, cv, "x.csv") == []
