"""Full-table error metrics against a ground truth: each checked on a case whose answer is known."""

import numpy as np
import pytest

from reconstruction.core import merlgrid, merltable, metrics
from reconstruction.core.models import Material

MAT = Material.from_dict({"name": "m", "lobes": [{"type": "lambert", "albedo": [0.2, 0.4, 0.6]},
                                                 {"type": "ggx", "alpha": 0.2, "specular": 0.5}]})


@pytest.fixture(scope="module")
def truth():
    return merltable.tabulate(MAT.eval)


def test_a_table_equals_itself(truth):
    e = metrics.table_errors(truth, truth)
    assert e == {"rel_rmse_cos": 0.0, "log_rmse": 0.0, "sphere_rel_error": 0.0, "albedo_max_abs_error": 0.0}


def test_a_uniform_scale_gives_the_expected_errors(truth):
    scaled = truth * 1.1
    assert metrics.relative_rmse_cos(scaled, truth) == pytest.approx(0.1, rel=1e-9)
    assert metrics.sphere_relative_error(scaled, truth) == pytest.approx(0.1, rel=1e-5)
    # with eps -> 0 the log error of a uniform scale is ln(1.1) everywhere
    assert metrics.log_rmse(scaled, truth, eps=1e-12) == pytest.approx(np.log(1.1), rel=1e-3)
    a = metrics.albedo_error(scaled, truth)
    np.testing.assert_allclose(a["albedo"], 1.1 * np.array(a["truth_albedo"]), rtol=1e-9)
    assert a["max_abs_error"] == pytest.approx(0.1 * max(a["truth_albedo"]), rel=1e-9)


def test_truth_albedo_of_a_lambert_table_is_its_albedo():
    lam = Material.from_dict({"name": "l", "lobes": [{"type": "lambert", "albedo": 0.5}]})
    t = merltable.tabulate(lam.eval)
    a = metrics.albedo_error(t, t, theta_i_deg=[0.0, 40.0])
    np.testing.assert_allclose(a["truth_albedo"], 0.5, rtol=2e-3)


def test_log_rmse_weighs_the_floor_where_relative_rmse_sees_the_peak(truth):
    wi, wo = merlgrid.cell_to_dirs(*np.meshgrid(np.arange(90), np.arange(90), np.arange(180), indexing="ij"))
    c = np.clip(wi[..., 2], 0, None) * np.clip(wo[..., 2], 0, None)
    weighted = np.nan_to_num(truth) * c
    dim = truth.copy()
    dim[weighted < 0.02 * weighted.max()] *= 0.5  # halve only the dim cells, a large part of the table
    assert metrics.relative_rmse_cos(dim, truth) < 0.05
    assert metrics.log_rmse(dim, truth, eps=1e-6) > 0.2  # ln 2 on ~14 % of the cells


def test_rmse_by_theta_d_splits_the_error_where_it_lies(truth):
    """An error placed only at grazing theta_d (>= 60 deg) shows in that band alone, and the bands' squares add
    up to the whole relative RMSE."""
    off = truth.copy()
    off[:, :, 70:80, :] *= 1.5  # theta_d bins 70..79 deg only
    off[:, 0:5, 10:20, :] *= 0.9  # a smaller error at theta_d 10..19 deg
    parts = metrics.relative_rmse_cos_by_theta_d(off, truth, 80.0, (0.0, 30.0, 60.0, 90.0))
    whole = metrics.relative_rmse_cos(off, truth, 80.0)
    assert parts.shape == (3,)
    assert np.sum(parts**2) == pytest.approx(whole**2, rel=1e-9)
    assert parts[1] == 0.0 and parts[0] > 0.0 and parts[2] > parts[0]
    np.testing.assert_allclose(metrics.relative_rmse_cos_by_theta_d(truth, truth, 80.0), 0.0)
