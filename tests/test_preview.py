"""Sphere preview: the rendered radiance is f E cos, the EXR round-trips, the PNG decodes."""

import struct
import zlib

import numpy as np
import OpenEXR
import pytest

from reconstruction.core import merltable
from reconstruction.core.models import Material
from reconstruction.core.render import PREVIEW_LIGHT_POSITION as LIGHT_POSITION
from reconstruction.core.render import render_point_light as render_sphere
from reconstruction.report.preview import AMBIENT, PREVIEW_RADIUS, render_preview, srgb_encode, write_preview


def material(*lobes):
    return Material.from_dict({"name": "m", "lobes": list(lobes)})


def pixel_normal(size, row, col):
    x = (col + 0.5) / size * 2 - 1
    y = -((row + 0.5) / size * 2 - 1)
    return np.array([x, y, np.sqrt(1 - x * x - y * y)])


def test_lambertian_sphere_radiance_by_hand():
    size = 64
    img = render_sphere(material({"type": "lambert", "albedo": [0.2, 0.4, 0.8]}).eval, size)
    assert img.dtype == np.float32 and img.shape == (size, size, 3)
    for row, col in [(32, 32), (20, 15), (40, 50)]:
        n = pixel_normal(size, row, col)
        to_l = LIGHT_POSITION - n
        r2 = to_l @ to_l
        cos_i = max(n @ to_l / np.sqrt(r2), 0.0)
        expected = np.array([0.2, 0.4, 0.8]) / np.pi * cos_i * (LIGHT_POSITION @ LIGHT_POSITION) / r2
        np.testing.assert_allclose(img[row, col], expected, rtol=1e-5)
    assert np.all(img[0, 0] == 0) and np.all(img[-1, -1] == 0)  # corners are outside the sphere
    # the lit side (towards the light, upper left) is brighter than the far side
    assert img[16, 16].sum() > 10 * img[48, 48].sum()


def test_highlight_sits_at_the_mirror_direction():
    size = 128
    img = render_sphere(material({"type": "ggx", "alpha": 0.05, "specular": 1.0}).eval, size)
    row, col = np.unravel_index(np.argmax(img[..., 0]), img.shape[:2])
    n = pixel_normal(size, row, col)
    h = (LIGHT_POSITION - n) / np.linalg.norm(LIGHT_POSITION - n) + np.array([0, 0, 1.0])
    h /= np.linalg.norm(h)
    assert np.degrees(np.arccos(np.clip(n @ h, -1, 1))) < 2.0


def test_table_render_matches_analytic_render():
    mat = material({"type": "lambert", "albedo": [0.05, 0.1, 0.4]}, {"type": "ggx", "alpha": 0.3, "specular": 0.5})
    a = render_sphere(mat.eval, 48)
    b = render_sphere(merltable.brdf_of(merltable.tabulate(mat.eval)), 48)
    assert np.abs(a - b).sum() / a.sum() < 0.01


def read_png(path):
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    pos, chunks = 8, {}
    while pos < len(data):
        (n,) = struct.unpack(">I", data[pos:pos + 4])
        kind = data[pos + 4:pos + 8]
        body = data[pos + 8:pos + 8 + n]
        (crc,) = struct.unpack(">I", data[pos + 8 + n:pos + 12 + n])
        assert crc == zlib.crc32(kind + body) & 0xFFFFFFFF
        chunks[kind] = chunks.get(kind, b"") + body
        pos += 12 + n
    w, h, depth, ctype = struct.unpack(">IIBB", chunks[b"IHDR"][:10])
    raw = np.frombuffer(zlib.decompress(chunks[b"IDAT"]), np.uint8).reshape(h, 1 + 3 * w)
    assert np.all(raw[:, 0] == 0) and depth == 8 and ctype == 2
    return raw[:, 1:].reshape(h, w, 3)


def test_write_preview_exr_and_png(tmp_path):
    mat = material({"type": "lambert", "albedo": [0.1, 0.3, 0.6]}, {"type": "ggx", "alpha": 0.2, "specular": 0.3})
    table = merltable.tabulate(mat.eval)
    info = write_preview(tmp_path / "m.exr", table, size=40)
    with OpenEXR.File(str(tmp_path / "m.exr")) as f:
        px = f.channels()["RGB"].pixels
    ref = render_preview(merltable.brdf_of(table), 40)
    assert px.dtype == np.float32 and px.shape == (40, 40, 3)
    np.testing.assert_array_equal(px, ref)
    png = read_png(tmp_path / "m.png")
    assert png.shape == (40, 40, 3)
    expected = np.round(srgb_encode(ref * info["png_exposure"]) * 255).astype(np.uint8)
    np.testing.assert_array_equal(png, expected)
    assert png[..., 2].max() == 255
    # the background is the environment: a neutral grey, neither black nor white
    assert len(set(png[0, 0])) == 1 and 60 < png[0, 0, 0] < 200
    assert info["ambient_radiance"] == AMBIENT


def test_preview_has_a_margin_and_an_environment_that_lights_the_unlit_side():
    size = 80
    albedo = np.array([0.2, 0.4, 0.8])
    img = render_preview(material({"type": "lambert", "albedo": albedo.tolist()}).eval, size)
    np.testing.assert_allclose(img[0, 0], AMBIENT)  # the background is the environment's radiance
    np.testing.assert_allclose(img[size // 2, 2], AMBIENT)  # the margin: the sphere does not reach the edge
    # on the far side from the light: the key light's term plus the environment's, which a Lambertian reflects
    # as albedo * ambient whatever the view angle
    x, y = 0.7 * PREVIEW_RADIUS, -0.55 * PREVIEW_RADIUS
    col, row = int((x + 1) / 2 * size), int((1 - y) / 2 * size)
    direct = render_sphere(material({"type": "lambert", "albedo": albedo.tolist()}).eval, size,
                           radius=PREVIEW_RADIUS)[row, col]
    np.testing.assert_allclose(img[row, col] - direct, AMBIENT * albedo, rtol=0.01)


def test_srgb_encode_endpoints():
    assert srgb_encode(0.0) == 0.0 and srgb_encode(1.0) == pytest.approx(1.0)
    assert srgb_encode(0.0031308) == pytest.approx(0.04045, abs=1e-5)
    assert srgb_encode(0.18) == pytest.approx(0.4614, abs=1e-3)
