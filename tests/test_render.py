"""The sphere renderer (reconstruction.core.render) against brute-force integrals, and the image metrics built on it."""

import math

import numpy as np
import pytest

from reconstruction.core import render
from reconstruction.core.metrics import image_errors, image_exposure, image_psnr, image_relative_rmse, tone_map
from reconstruction.core.models import Material
from reconstruction.core.render import Lighting, PointLight, SkyGround, Sun, render_sphere


def material(*lobes):
    return Material.from_dict({"name": "m", "lobes": list(lobes)})


LAMBERT = material({"type": "lambert", "albedo": [0.2, 0.5, 0.8]})
GGX = material({"type": "ggx", "alpha": 0.2, "specular": 1.0, "f0": 0.04})


def pixel_normal(size, row, col):
    x = (col + 0.5) / size * 2 - 1
    y = -((row + 0.5) / size * 2 - 1)
    return np.array([x, y, math.sqrt(max(0.0, 1 - x * x - y * y))])


def brute_force(f, env, n, n_theta=300, n_phi=600):
    """The environment's radiance at the sphere point of normal ``n``, seen along -z: Gauss-Legendre in cos theta x
    the midpoint rule in phi over the local hemisphere, in a frame of the test's own (tangent = up x n)."""
    t = np.cross([0.0, 1.0, 0.0], n)
    t /= np.linalg.norm(t)
    b = np.cross(n, t)
    x, wx = np.polynomial.legendre.leggauss(n_theta)
    mu, wmu = 0.5 * (x + 1.0), 0.5 * wx
    phi = (np.arange(n_phi) + 0.5) / n_phi * 2 * np.pi
    st = np.sqrt(1 - mu ** 2)
    wi = np.stack([st[:, None] * np.cos(phi), st[:, None] * np.sin(phi),
                   np.broadcast_to(mu[:, None], (n_theta, n_phi))], -1).reshape(-1, 3)
    w = ((wmu * mu)[:, None] * np.full(n_phi, 2 * np.pi / n_phi)).reshape(-1)
    view = np.array([0.0, 0.0, 1.0])
    wo = np.broadcast_to([view @ t, view @ b, view @ n], wi.shape)
    world_y = wi @ np.array([t[1], b[1], n[1]])
    return (w * env.radiance(world_y)) @ np.asarray(f(wi, wo)).reshape(wi.shape[0], -1)


# pixels of a 64 x 64 image: the centre, facing the sky, facing the ground, the horizon through the local
# hemisphere, and grazing views at the rim (view angles 1 to 85 deg)
PIXELS = [(32, 32), (10, 20), (50, 45), (2, 30), (60, 30), (20, 55), (45, 8), (32, 2), (30, 61), (16, 4), (58, 14)]


@pytest.mark.parametrize("mat", [LAMBERT, GGX], ids=["lambert", "ggx-alpha-0.2-fresnel"])
def test_environment_matches_a_brute_force_integral(mat):
    size = 64
    env = SkyGround()
    img = render_sphere(mat.eval, size, "environment")
    assert img.shape == (size, size, np.asarray(mat.eval(np.eye(3)[2:], np.eye(3)[2:])).shape[-1])
    views = render.view_angle_deg(size)
    assert max(views[r, c] for r, c in PIXELS) > 80  # the rim is among them
    errs = []
    for r, c in PIXELS:
        ref = brute_force(mat.eval, env, pixel_normal(size, r, c))
        errs.append(np.abs(img[r, c] / ref - 1.0).max())
    errs = np.array(errs)
    assert errs.max() < 0.04, dict(zip(PIXELS, errs.round(4), strict=True))  # measured: at most 2.8 %
    assert np.sqrt(np.mean(errs ** 2)) < 0.015, errs  # measured: 1.0 % (ggx), 0.9 % (lambert)


@pytest.mark.slow
def test_a_mirror_like_lobe_at_the_rim_is_integrated():
    """A sharp lobe (GGX alpha 0.01) at grazing views: a fixed set of world directions sees it at a handful of
    directions at most (the blotches of the old environment sphere); the lobe's own samples integrate it."""
    size = 64
    sharp = material({"type": "ggx", "alpha": 0.01, "specular": 1.0})
    img = render_sphere(sharp.eval, size, "environment")
    for r, c in [(32, 2), (16, 4), (5, 40), (32, 32)]:
        ref = brute_force(sharp.eval, SkyGround(), pixel_normal(size, r, c), 1200, 2400)
        assert img[r, c, 0] == pytest.approx(ref[0], rel=0.04)


def test_suns_and_point_lights_by_hand():
    size = 32
    sun = Sun((-1.0, 2.0, 2.0), irradiance=2.5)
    img = render_sphere(LAMBERT.eval, size, Lighting(suns=(sun,)))
    s = np.array(sun.direction) / 3.0
    for r, c in [(16, 16), (8, 10), (25, 20)]:
        n = pixel_normal(size, r, c)
        expected = np.array([0.2, 0.5, 0.8]) / np.pi * 2.5 * max(n @ s, 0.0)
        np.testing.assert_allclose(img[r, c], expected, rtol=1e-9, atol=1e-12)
    pl = PointLight((2.0, -1.0, 4.0), 21.0)
    img = render_sphere(LAMBERT.eval, size, Lighting(points=(pl,)))
    n = pixel_normal(size, 20, 22)
    d = np.array(pl.position) - n
    expected = np.array([0.2, 0.5, 0.8]) / np.pi * 21.0 * max(n @ d, 0.0) / np.linalg.norm(d) / (d @ d)
    np.testing.assert_allclose(img[20, 22], expected, rtol=1e-9)


def test_the_render_is_deterministic_linear_and_keeps_the_channels():
    grey = material({"type": "lambert", "albedo": 0.5}, {"type": "ggx", "alpha": 0.1, "specular": 0.5})
    a = render_sphere(grey.eval, 40, "key")
    assert a.shape == (40, 40, 1)
    assert np.array_equal(a, render_sphere(grey.eval, 40, "key"))  # the same image at every call
    b = render_sphere(lambda wi, wo: 2.0 * grey.eval(wi, wo), 40, "key")
    np.testing.assert_allclose(b, 2.0 * a, rtol=1e-12)
    assert np.all(a[0, 0] == 0) and np.all(a[20, 20] > 0)  # black outside the sphere


def test_presets_light_the_front_and_the_rim():
    size = 64
    key = render_sphere(LAMBERT.eval, size, Lighting(suns=render.PRESETS["key"].suns))
    rim = render_sphere(LAMBERT.eval, size, Lighting(suns=render.PRESETS["rim"].suns))
    views = render.view_angle_deg(size)
    lit_key, lit_rim = key[..., 0] > 0, rim[..., 0] > 0
    # the key sun (in front) lights the disc's centre and peaks where the normal faces it
    assert lit_key[32, 32] and lit_key.sum() > 0.5 * np.isfinite(views).sum()
    r, c = np.unravel_index(np.argmax(key[..., 0]), key.shape[:2])
    s = np.array(render.KEY_SUN_DIRECTION) / np.linalg.norm(render.KEY_SUN_DIRECTION)
    assert pixel_normal(size, r, c) @ s > 0.99
    # the rim sun (behind) lights only a crescent seen at grazing views, at the upper right
    assert not lit_rim[32, 32] and lit_rim.any()
    assert np.nanmin(np.where(lit_rim, views, np.nan)) > 40
    rows, cols = np.nonzero(lit_rim)
    assert rows.mean() < size / 2 and cols.mean() > size / 2
    with pytest.raises(ValueError, match="unknown lighting 'sunset'"):
        render_sphere(LAMBERT.eval, 8, "sunset")


def test_antialiased_edges_cover_the_disc_area():
    size, radius = 64, 0.8
    cov = render.sphere_coverage(size, radius, antialias=True)
    edge = (cov > 0) & (cov < 1)
    assert edge.sum() > 0.5 * 2 * np.pi * radius * size / 2  # a ring of partial pixels all round
    area = np.pi * (radius * size / 2) ** 2
    assert cov.sum() == pytest.approx(area, rel=0.005)
    hard = render.sphere_coverage(size, radius)
    assert set(np.unique(hard)) == {0.0, 1.0}
    img = render_sphere(LAMBERT.eval, size, "key", radius, antialias=True)
    assert np.all(img[edge & (cov < 0.5)].sum(axis=-1) < img[edge & (cov > 0.5)].sum(axis=-1).max())
    mask, normals = render.sphere_normals(size, radius, antialias=True)
    assert np.array_equal(mask, cov > 0) and np.all(normals[:, 2] > 0)


def test_view_angle_mask_keeps_the_views_up_to_80_degrees():
    size = 256
    m = render.view_angle_mask(size, 1.0, 80.0)
    disc = render.view_angle_mask(size, 1.0, 90.0)
    # the disc's points seen at up to 80 deg lie within radius sin 80
    assert m.sum() / disc.sum() == pytest.approx(math.sin(math.radians(80)) ** 2, rel=0.01)
    assert m[128, 128] and not m[128, 1] and not m[0, 0]


def test_image_metrics_by_hand():
    rng = np.random.default_rng(1)
    truth = rng.uniform(0.0, 2.0, (16, 16, 3))
    mask = np.ones((16, 16), dtype=bool)
    mask[:4] = False
    e = image_exposure(truth, mask)
    assert e == pytest.approx(1.0 / np.percentile(truth[mask], 99.5))
    np.testing.assert_allclose(tone_map(truth, e), np.clip(truth * e, 0, 1) ** (1 / 2.2))
    img = truth * 1.1
    assert image_relative_rmse(img, truth, mask) == pytest.approx(0.1)
    mse = np.mean((tone_map(img, e)[mask] - tone_map(truth, e)[mask]) ** 2)
    assert image_psnr(img, truth, mask) == pytest.approx(10 * np.log10(1 / mse))
    img[~mask] = 100.0  # outside the mask: ignored
    assert image_relative_rmse(img, truth, mask) == pytest.approx(0.1)
    assert image_psnr(truth, truth, mask) == float("inf")


def test_image_errors_of_two_brdfs():
    brighter = material({"type": "lambert", "albedo": [0.22, 0.55, 0.88]})
    out = image_errors(brighter.eval, LAMBERT.eval, size=48)
    assert set(out) == {"key", "rim"}
    for name in ("key", "rim"):  # the render is linear in f: 10 % more f is 10 % more light everywhere
        assert out[name]["relative_rmse"] == pytest.approx(0.1, rel=1e-6)
        assert 10 < out[name]["psnr_db"] < 60
    same = image_errors(LAMBERT.eval, LAMBERT.eval, size=32)
    assert same["key"]["relative_rmse"] == 0 and same["key"]["psnr_db"] == float("inf")
