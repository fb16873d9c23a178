"""Numerical stability at the extremes: grazing angles, theta_h = 0, sharp and rough lobes, 1e8 dynamic range,
zero and negative samples, tiny slices, NaN/inf input, float32 input. Every table a method writes is finite and
non-negative above the horizon; every failure is a clear error; no fit returns NaN parameters."""

import math

import numpy as np
import pytest

from reconstruction import pipeline
from reconstruction.base import ReconstructionError
from reconstruction.core import merlgrid, merltable
from reconstruction.core.geometry import half_diff_from_dirs, inplane_to_dirs
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice

METHODS = ["fit", "bivariate", "revolve", "auto"]
SHARP = Material.from_dict({"name": "sharp", "lobes": [{"type": "lambert", "albedo": 1e-8},
                                                        {"type": "ggx", "alpha": 1e-3, "specular": 1.0}]})
ROUGH = Material.from_dict({"name": "rough", "lobes": [{"type": "ggx", "alpha": 1.0, "specular": 0.9}]})
DIFFUSE = Material.from_dict({"name": "dark", "lobes": [{"type": "lambert", "albedo": 0.02}]})


def inplane_slice(mat, incidences, theta_o, dtype=np.float64, noise=0.0, seed=0):
    ti = np.repeat(np.asarray(incidences, float), len(theta_o))
    to = np.tile(np.asarray(theta_o, float), len(incidences))
    keep = np.abs(ti + to) > 2.0  # the retro blind spot
    ti, to = ti[keep], to[keep]
    f = mat.eval(*inplane_to_dirs(np.radians(ti), np.radians(to)))
    if noise:
        f = f + np.random.default_rng(seed).normal(0.0, noise, f.shape)
    return Slice(ti.astype(dtype), to.astype(dtype), f.astype(dtype), ["value"] if f.shape[1] == 1 else
                 ["R", "G", "B"], np.full(f.shape, max(noise, 1e-9), dtype=dtype), meta={"quantity": "brdf"})


def check_table(rec):
    table = pipeline.tabulate(rec)  # raises if a cell above the horizon is not finite or negative
    above = table[:, merlgrid.valid_mask()]
    assert np.all(np.isfinite(above)) and np.all(above >= 0)
    if rec.method == "fit":
        for lobe in rec.report()["parameters"]:
            for k, v in lobe.items():
                if isinstance(v, float):
                    assert math.isfinite(v), (k, v)
                elif isinstance(v, list):
                    assert all(math.isfinite(x) for x in v), (k, v)
    return table


# outgoing angles to 89.9 deg, including the mirror direction of every incidence exactly (theta_h = 0)
GRAZING_TO = np.unique(np.concatenate([np.linspace(-89.9, 89.9, 121), [0.0, 45.0, 89.9]]))


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_sharp_lobe_with_1e8_dynamic_range_at_grazing_angles(method):
    s = inplane_slice(SHARP, [0.0, 45.0, 89.9], GRAZING_TO)
    f = s.values[:, 0]
    assert f.max() / f[f > 0].min() > 1e8  # peak (theta_h = 0) over the lambert floor
    rec, _ = pipeline.reconstruct(s, method)
    check_table(rec)


@pytest.mark.parametrize("method", METHODS)
def test_very_rough_lobe(method):
    check_table(pipeline.reconstruct(inplane_slice(ROUGH, [30.0], np.linspace(-89.9, 89.9, 91)), method)[0])


@pytest.mark.parametrize("method", METHODS)
def test_negative_samples_after_dark_subtraction(method):
    s = inplane_slice(DIFFUSE, [20.0, 60.0], np.linspace(-85, 85, 69), noise=0.004)
    assert (s.values < 0).any()  # noise around a dim value gives negative readings
    check_table(pipeline.reconstruct(s, method)[0])


@pytest.mark.slow
@pytest.mark.parametrize("method", METHODS)
def test_float32_input(method):
    s = inplane_slice(Material.from_toml("configs/simulated.toml"), [30.0], np.linspace(-80, 80, 81),
                      dtype=np.float32)
    check_table(pipeline.reconstruct(s, method)[0])


@pytest.mark.parametrize("method", METHODS)
def test_degenerate_input_gives_a_clear_error(method):
    zero = Slice(np.full(20, 30.0), np.linspace(-80, 80, 20), np.zeros((20, 1)), ["value"])
    with pytest.raises(ReconstructionError, match="zero"):
        pipeline.reconstruct(zero, method)
    one = Slice([30.0], [10.0], [[0.3]], ["value"])
    with pytest.raises(ReconstructionError, match="sample"):
        pipeline.reconstruct(one, method)
    for bad in (np.nan, np.inf):
        v = np.full((20, 1), 0.3)
        v[5] = bad
        s = Slice(np.full(20, 30.0), np.linspace(-80, 80, 20), v, ["value"])
        with pytest.raises(ReconstructionError, match="value"):
            pipeline.reconstruct(s, method)


def test_theta_h_zero_and_grazing_pairs_are_finite_in_every_model():
    ti = np.radians([0.0, 45.0, 89.9, 89.9])
    to = np.radians([0.0, 45.0, 89.9, -89.9])
    wi, wo = inplane_to_dirs(ti, to)
    assert half_diff_from_dirs(wi, wo)[0][:3].tolist() == [0.0, 0.0, 0.0] or np.allclose(
        half_diff_from_dirs(wi, wo)[0][:3], 0.0, atol=1e-12)
    for mat in (SHARP, ROUGH, DIFFUSE):
        v = mat.eval(wi, wo)
        assert np.all(np.isfinite(v)) and np.all(v >= 0)


class _EvalOnly:
    """A reconstruction with eval only (no table of its own), as a user's plug-in method might be."""

    method = "eval-only"

    def __init__(self, mat, sharp):
        self._mat, self.sharp_theta_h_rad = mat, sharp

    def eval(self, wi, wo):
        return self._mat.eval(wi, wo)


@pytest.mark.slow
def test_tabulate_without_a_table_averages_a_sharp_lobe_over_its_cells():
    """pipeline.tabulate's fallback for a method without table(): bin-centre values, and where the method names a
    lobe sharper than the cells (sharp_theta_h_rad), theta_h cell averages there, each theta_d row scaled to the
    lobe's energy (reconstruction.core.sharprows); negative values refused."""
    point = merltable.tabulate(SHARP.eval)
    plain = pipeline.tabulate(_EvalOnly(SHARP, None))
    np.testing.assert_array_equal(plain, point)
    avg = pipeline.tabulate(_EvalOnly(SHARP, 0.01))
    ref, rows = merltable.average_theta_h_cells(SHARP.eval, point, 0.01, n=8)
    valid = merlgrid.valid_mask()
    # the cell averages' shape in theta_h and phi_d is kept: one positive factor per channel and theta_d row
    ratio = np.where(valid[None, :rows], avg[:, :rows] / np.where(ref[:, :rows] > 0, ref[:, :rows], np.nan), np.nan)
    per_row = np.nanmedian(ratio, axis=(1, 3))
    assert np.all(per_row > 0.25) and np.all(per_row < 4.0)
    known = np.isfinite(ratio)
    np.testing.assert_allclose(ratio[known], np.broadcast_to(per_row[:, None, :, None], ratio.shape)[known], rtol=1e-9)
    assert rows >= 1 and not np.allclose(avg[:, :rows][:, valid[:rows]], point[:, :rows][:, valid[:rows]])
    np.testing.assert_array_equal(avg[:, rows:], point[:, rows:])  # beyond the sharp rows: bin centres
    neg = _EvalOnly(SHARP, None)
    neg.eval = lambda wi, wo: -SHARP.eval(wi, wo)
    with pytest.raises(ReconstructionError, match="negative"):
        pipeline.tabulate(neg)
