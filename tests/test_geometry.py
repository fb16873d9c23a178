"""Geometry conventions: spherical <-> vectors, in-plane samples, Rusinkiewicz transform, thesis points."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from reconstruction.core import geometry as g

RNG = np.random.default_rng(7)


def random_dirs(n, rng=RNG):
    theta = np.arccos(rng.uniform(0.0, 1.0, n))  # upper hemisphere
    phi = rng.uniform(-np.pi, np.pi, n)
    return g.sph_to_vec(theta, phi)


def test_spherical_round_trip_any_batch_shape():
    theta = RNG.uniform(1e-6, np.pi - 1e-6, (4, 5, 6))
    phi = RNG.uniform(-np.pi + 1e-9, np.pi, (4, 5, 6))
    v = g.sph_to_vec(theta, phi)
    assert v.shape == (4, 5, 6, 3)
    np.testing.assert_allclose(np.linalg.norm(v, axis=-1), 1.0, atol=1e-15)
    t2, p2 = g.vec_to_sph(v)
    np.testing.assert_allclose(t2, theta, atol=1e-12)
    np.testing.assert_allclose(p2, phi, atol=1e-12)


def test_inplane_convention_light_on_minus_x_and_specular_positive():
    wi, wo = g.inplane_to_dirs(np.radians(30.0), np.radians(30.0))
    assert wi[0] < 0 and wi[2] > 0  # light on the -x side
    mirror = np.array([-wi[0], -wi[1], wi[2]])
    np.testing.assert_allclose(wo, mirror, atol=1e-15)  # +theta_o = theta_i is the mirror direction
    wi, wo = g.inplane_to_dirs(np.radians(30.0), np.radians(-30.0))
    np.testing.assert_allclose(wo, wi, atol=1e-15)  # -theta_i is the retro direction
    ti, to = g.dirs_to_inplane(*g.inplane_to_dirs(np.radians([10.0, 80.0]), np.radians([-45.0, 89.9])))
    np.testing.assert_allclose(np.degrees(ti), [10.0, 80.0], atol=1e-12)
    np.testing.assert_allclose(np.degrees(to), [-45.0, 89.9], atol=1e-12)


def test_half_diff_round_trip():
    wi = random_dirs(20000)
    wo = random_dirs(20000)
    th, ph, td, pd = g.half_diff_from_dirs(wi, wo)
    wi2, wo2 = g.dirs_from_half_diff(th, ph, td, pd)
    np.testing.assert_allclose(wi2, wi, atol=1e-12)
    np.testing.assert_allclose(wo2, wo, atol=1e-12)


def test_half_diff_inverse_round_trip_from_angles():
    n = 20000
    th = RNG.uniform(1e-3, np.pi / 2 - 1e-3, n)
    ph = RNG.uniform(-np.pi + 1e-3, np.pi - 1e-3, n)
    td = RNG.uniform(1e-3, np.pi / 2 - 1e-3, n)
    pd = RNG.uniform(-np.pi + 1e-3, np.pi - 1e-3, n)
    back = g.half_diff_from_dirs(*g.dirs_from_half_diff(th, ph, td, pd))
    for a, b in zip(back, (th, ph, td, pd), strict=True):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_swapping_wi_and_wo_maps_phi_d_to_phi_d_plus_pi():
    wi = random_dirs(5000)
    wo = random_dirs(5000)
    th1, ph1, td1, pd1 = g.half_diff_from_dirs(wi, wo)
    th2, ph2, td2, pd2 = g.half_diff_from_dirs(wo, wi)
    np.testing.assert_allclose(th2, th1, atol=1e-12)
    np.testing.assert_allclose(td2, td1, atol=1e-12)
    diff = np.mod(pd2 - pd1, 2 * np.pi)
    np.testing.assert_allclose(diff, np.pi, atol=1e-9)


@settings(max_examples=200, deadline=None)
@given(st.floats(0.0, 89.9), st.floats(-89.9, 89.9))
def test_inplane_pairs_land_on_phi_d_0_or_pi(ti_deg, to_deg):
    wi, wo = g.inplane_to_dirs(np.radians(ti_deg), np.radians(to_deg))
    th, _, td, pd = g.half_diff_from_dirs(wi, wo)
    ti = np.radians(ti_deg)
    # theta_d = theta_i +- theta_h
    assert min(abs(td - (ti + th)), abs(td - abs(ti - th))) < 1e-9
    if td > 1e-6:  # phi_d is undefined when d is the normal (retro direction)
        assert min(abs(np.sin(pd)), abs(abs(pd) - np.pi)) < 1e-9


def test_normal_incidence_and_theta_h_zero_are_finite():
    # normal incidence, normal exitance: h = n, theta_h = 0, d = n
    wi, wo = g.inplane_to_dirs(0.0, 0.0)
    out = g.half_diff_from_dirs(wi, wo)
    assert all(np.isfinite(x) for x in out)
    assert out[0] == 0.0 and out[2] == 0.0
    # mirror pairs: theta_h = 0 exactly up to rounding, 1 + eps in a dot product must not become NaN
    ti = np.radians(np.linspace(0, 89.9, 1000))
    wi, wo = g.inplane_to_dirs(ti, ti)
    th, ph, td, pd = g.half_diff_from_dirs(wi, wo)
    assert np.all(np.isfinite(th)) and np.all(np.isfinite(td)) and np.all(np.isfinite(pd))
    np.testing.assert_allclose(th, 0.0, atol=1e-12)
    np.testing.assert_allclose(td, ti, atol=1e-12)
    # opposite directions (h undefined) still give finite angles
    assert all(np.isfinite(x) for x in g.half_diff_from_dirs([1.0, 0, 0], [-1.0, 0, 0]))
    assert g.safe_acos(1.0 + 1e-15) == 0.0


def test_rodrigues_matches_axis_rotations():
    v = random_dirs(100)
    a = RNG.uniform(-np.pi, np.pi, 100)
    np.testing.assert_allclose(g.rodrigues(v, [0, 0, 1.0], a), g.rotate_z(v, a), atol=1e-12)
    np.testing.assert_allclose(g.rodrigues(v, [0, 1.0, 0], a), g.rotate_y(v, a), atol=1e-12)


def test_thesis_points_round_trip_and_translation():
    # thesis: elevation "phi" above the surface, azimuth "theta"
    v = g.thesis_to_vec(np.radians(90.0), 0.0, 2.0)
    np.testing.assert_allclose(v, [0, 0, 2.0], atol=1e-15)  # elevation 90 = along the normal
    v = g.thesis_to_vec(np.radians(0.0), np.radians(90.0), 1.0)
    np.testing.assert_allclose(v, [0, 1.0, 0], atol=1e-15)  # elevation 0, azimuth 90 = +y on the surface
    p = random_dirs(1000) * RNG.uniform(0.1, 3.0, (1000, 1))
    el, az, r = g.vec_to_thesis(p)
    np.testing.assert_allclose(g.thesis_to_vec(el, az, r), p, atol=1e-12)
    to = np.radians(np.linspace(-89, 89, 50))
    val = RNG.uniform(0.1, 2, 50)
    to2, val2 = g.slice_from_thesis_points(g.thesis_points_from_slice(to, val))
    np.testing.assert_allclose(to2, to, atol=1e-12)
    np.testing.assert_allclose(val2, val, atol=1e-12)


@pytest.mark.parametrize("shape", [(), (3,), (2, 3, 4)])
def test_functions_keep_batch_shape(shape):
    ti = np.full(shape, 0.3)
    wi, wo = g.inplane_to_dirs(ti, -ti)
    assert wi.shape == shape + (3,)
    assert g.half_diff_from_dirs(wi, wo)[0].shape == shape
