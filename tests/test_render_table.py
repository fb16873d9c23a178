"""The renderer's fast path for tables (a cached sparse operator per image geometry and lighting) gives the
values of the generic path (every pair looked up in the table), synthetic tables only."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.core import merlgrid, merltable, render
from reconstruction.core.render import Lighting, PointLight, Quadrature, SkyGround, Sun, render_sphere

SMALL = Quadrature(n_cosine=13, alphas=(0.03, 0.3), n_per_alpha=9)


def _table(seed: int = 0) -> np.ndarray:
    """A smooth, coloured, non-trivial table with the format's invalid cells (below the horizon) as NaN."""
    th, td, pd = merlgrid.cell_angles()
    rng = np.random.default_rng(seed)
    lobe = np.exp(-(th / 0.2) ** 2) * (1.0 + np.cos(pd) * np.sin(td)) + 0.1 * (1 + td)
    t = np.stack([lobe * c for c in (0.3, 0.6, 1.2)]) * (1.0 + 0.05 * rng.random(merltable.SHAPE))
    return np.where(merlgrid.valid_mask()[None], t, np.nan)


def _generic(f):
    return lambda wi, wo: f(wi, wo)  # the same BRDF without the table's attributes: the generic path


@pytest.mark.parametrize("interpolate", [True, False])
@pytest.mark.parametrize("lighting", ["key", "rim", Lighting(points=(PointLight((-3.0, 3.0, 5.0), 34.0),))])
def test_a_table_renders_to_the_generic_paths_values(interpolate, lighting):
    f = merltable.brdf_of(_table(), interpolate=interpolate)
    assert hasattr(f, "table_cells")
    fast = render_sphere(f, 20, lighting, quadrature=SMALL)
    slow = render_sphere(_generic(f), 20, lighting, quadrature=SMALL)
    assert fast.shape == slow.shape == (20, 20, 3)
    assert slow.max() > 0
    np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-12 * slow.max())


def test_the_operator_is_reused_and_follows_the_tables_invalid_cells():
    render._operators.clear()
    t = _table(1)
    light = Lighting(SkyGround(), (Sun((1.0, 2.0, 3.0)),))
    a = render_sphere(merltable.brdf_of(t), 16, light, quadrature=SMALL)
    n_ops = len(render._operators)
    b = render_sphere(merltable.brdf_of(2.0 * t), 16, light, quadrature=SMALL)  # same cells: same operators, linear
    assert len(render._operators) == n_ops == 2  # the environment and the sun
    np.testing.assert_allclose(b, 2.0 * a, rtol=1e-12)
    # a table whose invalid cells differ (every cell of a theta_d row NaN): its own operator, the generic values
    holes = t.copy()
    holes[:, :, 10:14, :] = np.nan
    fast = render_sphere(merltable.brdf_of(holes), 16, light, quadrature=SMALL)
    assert len(render._operators) == n_ops + 2
    slow = render_sphere(_generic(merltable.brdf_of(holes)), 16, light, quadrature=SMALL)
    np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-12 * slow.max())
    assert not np.allclose(fast, a)


def test_channels_with_different_invalid_cells_take_the_generic_path():
    t = _table(2)
    t[1, 5:9, 20:30, :] = np.nan  # one channel only
    f = merltable.brdf_of(t)
    fast = render_sphere(f, 12, "key", quadrature=SMALL)
    slow = render_sphere(_generic(f), 12, "key", quadrature=SMALL)
    np.testing.assert_allclose(fast, slow, rtol=1e-10, atol=1e-12 * slow.max())


def test_lookup_cells_reproduce_the_lookup():
    rng = np.random.default_rng(3)
    t = _table(4)
    wi = rng.normal(size=(500, 3))
    wo = rng.normal(size=(500, 3))
    wi[:, 2], wo[:, 2] = np.abs(wi[:, 2]), np.abs(wo[:, 2])
    wi /= np.linalg.norm(wi, axis=1, keepdims=True)
    wo /= np.linalg.norm(wo, axis=1, keepdims=True)
    flat = t.reshape(3, -1)
    for interpolate in (True, False):
        idx, w = merltable.lookup_cells(wi, wo, interpolate)
        v = flat[:, idx]  # (3, N, K)
        fin = np.isfinite(v)
        ww = w[None] * fin
        got = np.sum(ww * np.nan_to_num(v), axis=-1) / np.sum(ww, axis=-1)
        want = merltable.lookup(t, wi, wo, interpolate).T
        np.testing.assert_allclose(got, want, rtol=1e-12)
