"""Preview renders: a sphere under a point light and a dim uniform environment, as linear OpenEXR + sRGB PNG.

:func:`render_sphere` (also the sphere of the error metric): world frame x right, y up, z towards the
orthographic camera; a unit sphere at the origin filling the frame, seen along -z; a point light of intensity
I = |L|^2 at L = (-3, 3, 5) (so the irradiance is about 1 near the sphere's front). Pixel value =
f(wi, wo) I cos(theta_i) / r^2 in the shading frame of the surface point (z = the sphere normal; any tangent, the
BRDF being isotropic); 0 outside the sphere.

:func:`render_preview` (what ``--preview`` writes) is the same sphere with a margin (radius 0.8 of the half frame)
and a uniform white environment of radiance ``ambient`` (default 0.05, against the key light's irradiance of
about 1) added everywhere: the sphere's unlit side reflects ambient * a(theta_o), a(theta_o) being the BRDF's
directional albedo at the view angle (by reciprocity, exactly what a uniform environment gives a convex object),
and the background shows the environment itself, a neutral grey distinct from the shadow. Every pixel is thus a
physical radiance of this scene, in the units of the key light.

The EXR holds linear values as float32 RGB; the PNG is the same image exposed so the 99.5th percentile of the
sphere's luminance maps to 1, clipped and sRGB-encoded. Both files are written atomically (temporary file, fsync,
rename): a failure (a full disk) never leaves a half-written image under the real name.
"""

from __future__ import annotations

import errno
import struct
import zlib
from collections.abc import Callable
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.atomic import atomic_open, atomic_path
from reconstruction.core import merltable
from reconstruction.core.render import PREVIEW_LIGHT_POSITION as LIGHT_POSITION
from reconstruction.core.render import render_point_light as render_sphere

Array = NDArray[np.float64]

__all__ = ["AMBIENT", "PREVIEW_RADIUS", "render_preview", "albedo_at_view", "write_exr", "write_png", "png_bytes",
           "srgb_encode", "write_preview"]

AMBIENT = 0.05
PREVIEW_RADIUS = 0.8


def albedo_at_view(f: Callable[[Array, Array], ArrayLike], cos_o: ArrayLike, n_nodes: int = 24) -> Array:
    """Directional albedo a(theta_o) = integral of f(wi, wo) cos(theta_i) d omega_i, (M, 3), at view cosines
    ``cos_o`` (M,): a quadrature at ``n_nodes`` view angles (64 x 128 directions each), interpolated in cos."""
    from reconstruction.core.metrics import directional_albedo

    nodes = np.linspace(0.02, 1.0, n_nodes)
    # by reciprocity a(theta_o) is the albedo of the swapped pair, which directional_albedo integrates
    alb = directional_albedo(lambda a, b: f(b, a), np.arccos(nodes), 64, 128)
    alb = np.repeat(alb, 3, axis=1) if alb.shape[1] == 1 else alb
    c = np.clip(np.asarray(cos_o, dtype=np.float64), nodes[0], 1.0)
    return np.stack([np.interp(c, nodes, alb[:, k]) for k in range(3)], axis=-1)


def render_preview(f: Callable[[Array, Array], ArrayLike], size: int = 256,
                   light_position: ArrayLike = LIGHT_POSITION, ambient: float = AMBIENT,
                   radius: float = PREVIEW_RADIUS) -> NDArray[np.float32]:
    """The preview image (size, size, 3) float32: :func:`render_sphere` with a margin plus the uniform
    environment of radiance ``ambient`` (see the module docstring)."""
    img = render_sphere(f, size, light_position, radius).astype(np.float64)
    c = ((np.arange(size) + 0.5) / size * 2.0 - 1.0) / radius
    x, y = np.meshgrid(c, -c)
    r2 = x * x + y * y
    inside = r2 < 1.0
    if ambient > 0:
        img[inside] += ambient * albedo_at_view(f, np.sqrt(1.0 - r2[inside]))  # view direction = +z
        img[~inside] = ambient
    return img.astype(np.float32)


def write_exr(path: str | Path, img: ArrayLike) -> None:
    """Write linear RGB (H, W, 3) as a float32 OpenEXR file (ZIP compression), atomically."""
    import OpenEXR

    rgb = np.ascontiguousarray(np.asarray(img, dtype=np.float32))
    if rgb.ndim != 3 or rgb.shape[2] != 3:
        raise ValueError(f"expected an (H, W, 3) image, got shape {rgb.shape}")
    header = {"compression": OpenEXR.ZIP_COMPRESSION, "type": OpenEXR.scanlineimage}
    with atomic_path(path) as tmp:
        try:
            with OpenEXR.File(header, {"RGB": rgb}) as exr:
                exr.write(tmp)
        except RuntimeError as e:  # OpenEXR reports write failures (a full disk) as RuntimeError
            msg = str(e).replace(tmp, str(path))
            raise OSError(errno.EIO, f"cannot write the OpenEXR image ({msg})", str(path)) from None


def srgb_encode(linear: ArrayLike) -> Array:
    """The sRGB transfer function (IEC 61966-2-1) of linear values in [0, 1]."""
    v = np.clip(np.asarray(linear, dtype=np.float64), 0.0, 1.0)
    return np.where(v <= 0.0031308, 12.92 * v, 1.055 * np.power(v, 1.0 / 2.4) - 0.055)


def _png_chunk(kind: bytes, data: bytes) -> bytes:
    return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data) & 0xFFFFFFFF)


def write_png(path: str | Path, img: ArrayLike, exposure: float | None = None) -> float:
    """Write linear RGB (H, W, 3) as an 8-bit sRGB PNG, atomically; returns the exposure used (a linear multiplier).

    ``exposure`` None: 1 / the 99.5th percentile of the non-zero pixels' luminance (1 if the image is black).
    """
    rgb = np.asarray(img, dtype=np.float64)
    h, w, _ = rgb.shape
    if exposure is None:
        lum = rgb @ np.array([0.2126, 0.7152, 0.0722])
        nz = lum[lum > 0]
        p = float(np.percentile(nz, 99.5)) if nz.size else 0.0
        exposure = 1.0 / p if p > 0 else 1.0
    data = png_bytes(np.round(srgb_encode(rgb * exposure) * 255.0).astype(np.uint8))
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return exposure


def png_bytes(px: ArrayLike, level: int = 6) -> bytes:
    """An 8-bit RGB image (H, W, 3) uint8 as the bytes of a PNG file (zlib ``level``)."""
    a = np.ascontiguousarray(px, dtype=np.uint8)
    h, w, _ = a.shape
    raw = np.concatenate([np.zeros((h, 1), np.uint8), a.reshape(h, w * 3)], axis=1)  # filter 0 on every row
    return (b"\x89PNG\r\n\x1a\n" + _png_chunk(b"IHDR", struct.pack(">IIBBBBB", w, h, 8, 2, 0, 0, 0))
            + _png_chunk(b"IDAT", zlib.compress(raw.tobytes(), level)) + _png_chunk(b"IEND", b""))


def _sphere_exposure(img: ArrayLike, radius: float) -> float | None:
    """1 / the 99.5th percentile of the luminance of the sphere's pixels (the background does not count)."""
    rgb = np.asarray(img, dtype=np.float64)
    size = rgb.shape[0]
    c = ((np.arange(size) + 0.5) / size * 2.0 - 1.0) / radius
    x, y = np.meshgrid(c, -c)
    lum = (rgb @ np.array([0.2126, 0.7152, 0.0722]))[x * x + y * y < 1.0]
    lum = lum[lum > 0]
    return 1.0 / float(np.percentile(lum, 99.5)) if lum.size and np.percentile(lum, 99.5) > 0 else None


def write_preview(exr_path: str | Path, table: ArrayLike, size: int = 256) -> dict[str, object]:
    """Render the MERL ``table`` (3, 90, 90, 180) with :func:`render_preview`; write ``exr_path`` and the PNG
    beside it."""
    exr_path = Path(exr_path)
    img = render_preview(merltable.brdf_of(table), size)
    write_exr(exr_path, img)
    png = exr_path.with_suffix(".png")
    exposure = write_png(png, img, _sphere_exposure(img, PREVIEW_RADIUS))
    return {"exr": str(exr_path), "png": str(png), "size": size, "light_position": LIGHT_POSITION.tolist(),
            "ambient_radiance": AMBIENT, "sphere_radius_of_half_frame": PREVIEW_RADIUS,
            "lighting": "point light of intensity |L|^2 at L plus a uniform white environment of radiance "
                        "ambient_radiance (also the background); linear radiance",
            "png_exposure": exposure, "max_linear": float(img.max())}
