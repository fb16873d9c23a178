"""A lobe far narrower than a table cell keeps its energy through tabulation (cell averages, not point samples)."""

import numpy as np
import pytest

from reconstruction.core import merltable
from reconstruction.core.geometry import inplane_to_dirs, sph_to_vec
from reconstruction.core.models import Material

SHARP = Material.from_dict({"name": "sharp", "lobes": [{"type": "ggx", "alpha": 1e-3, "specular": 1.0}]})
INCIDENCES_DEG = [0.0, 30.0, 60.0, 80.0]


def albedo_by_half_vectors(f, theta_i, n_theta=3000, n_phi=48):
    """integral f(wi, wo) cos theta_o d wo, integrated over half vectors h (d wo = 4 (wi . h) d wh).

    theta_h is sampled as u^4 (pi/2), dense near the normal, so both a lobe of width 1e-3 rad and the
    table's smallest theta_h cells (0.011 deg) are resolved.
    """
    u = (np.arange(n_theta) + 0.5) / n_theta
    th = u**4 * (np.pi / 2)
    dth = 4 * u**3 * (np.pi / 2) / n_theta
    ph = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    h = sph_to_vec(th[:, None], ph[None, :]).reshape(-1, 3)
    wh = (np.sin(th) * dth)[:, None].repeat(n_phi, 1).reshape(-1) * (2 * np.pi / n_phi)
    wi = np.broadcast_to(inplane_to_dirs(theta_i, 0.0)[0], h.shape)
    c = np.sum(wi * h, axis=-1)
    wo = 2 * c[:, None] * h - wi
    ok = (wo[:, 2] > 0) & (c > 0)
    v = np.asarray(f(wi[ok], wo[ok]))[:, 0]
    return float(np.sum(v * wo[ok, 2] * 4 * c[ok] * wh[ok]))


def as_renderer_reads(table):
    return lambda wi, wo: np.nan_to_num(merltable.lookup(table, wi, wo, interpolate=False))


@pytest.fixture(scope="module")
def tables():
    return merltable.tabulate(SHARP.eval), merltable.tabulate(SHARP.eval, supersample="adaptive")


@pytest.mark.parametrize("theta_i_deg", INCIDENCES_DEG)
def test_cell_averages_keep_the_energy_of_a_sub_cell_lobe(tables, theta_i_deg):
    _, averaged = tables
    ti = np.radians(theta_i_deg)
    own = albedo_by_half_vectors(SHARP.eval, ti)
    assert own == pytest.approx(1.0, abs=0.01)  # F = 1, no shadowing to speak of at alpha = 1e-3
    table = albedo_by_half_vectors(as_renderer_reads(averaged), ti)
    assert table == pytest.approx(own, rel=0.02)


def test_point_samples_at_bin_centres_do_not(tables):
    centres, _ = tables
    own = albedo_by_half_vectors(SHARP.eval, 0.0)
    table = albedo_by_half_vectors(as_renderer_reads(centres), 0.0)
    assert abs(table / own - 1) > 0.02  # the reason cell averages exist


def test_adaptive_equals_centre_values_where_f_is_linear_across_cells():
    lam = Material.from_dict({"name": "d", "lobes": [{"type": "lambert", "albedo": [0.2, 0.5, 0.9]}]})
    a = merltable.tabulate(lam.eval, supersample="adaptive")
    c = merltable.tabulate(lam.eval)
    np.testing.assert_array_equal(np.isnan(a), np.isnan(c))
    np.testing.assert_allclose(a[np.isfinite(a)], c[np.isfinite(c)], rtol=1e-12)
