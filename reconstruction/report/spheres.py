"""The HTML report's spheres: the written table rendered on a sphere under three point lights (with the preview's
dim uniform environment), under a sky-and-ground environment alone, and with a sun in front and one behind
(:mod:`reconstruction.core.render`), as linear images and as sRGB PNGs (no matplotlib). Numpy only: the
renders run in a thread of their own while a run goes on (:mod:`reconstruction.pipeline`)."""

from __future__ import annotations

import base64
from collections.abc import Callable, Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.core import merltable

Array = NDArray[np.float64]

__all__ = ["LIGHTS", "SPHERE_SIZE", "SPHERE_QUADRATURE", "N_DIRS", "environment_render", "sphere_images",
           "sphere_pngs"]

#: the point lights of the top row (position; intensity the squared distance: unit irradiance at the centre)
LIGHTS = {"upper left": (-3.0, 3.0, 5.0), "overhead": (0.0, 6.0, 2.0), "grazing right": (6.0, 0.5, 1.0)}


def environment_render(f: Callable[[Array, Array], ArrayLike], size: int = 112, radius: float = 0.8,
                       lighting: str = "environment") -> NDArray[np.float32]:
    """The sphere under the sky-and-ground environment of :mod:`reconstruction.core.render` (``lighting``: one of its
    presets: the environment alone, or with the ``key`` or ``rim`` sun), anti-aliased, over the environment as a
    dimmed backdrop (sky above, ground below): (size, size, 3) float32 linear RGB."""
    from reconstruction.core.render import SkyGround, render_sphere

    img = render_sphere(f, size, lighting, radius, antialias=True)
    return (_rgb(img) + _backdrop(size, radius, SkyGround())).astype(np.float32)


def _rgb(img: Array) -> Array:
    return np.repeat(img, 3, axis=2) if img.shape[2] == 1 else img


def _backdrop(size: int, radius: float, env: Any) -> Array:
    """The environment behind the sphere, dimmed (sky above the frame's middle, ground below), times the part of
    each pixel the sphere leaves uncovered."""
    from reconstruction.core.render import sphere_coverage

    y = -(((np.arange(size) + 0.5) / size) * 2.0 - 1.0)
    back = 0.35 * env.radiance(np.clip(y, -1.0, 1.0))[:, None] * np.ones(size)[None, :]
    return (back * (1.0 - sphere_coverage(size, radius, antialias=True)))[..., None] * np.ones(3)


#: The spheres' renders on the page: pixels per side, and the environment's quadrature (135 directions per pixel,
#: half the renderer's default: within about 1 % RMS of it on the demo's table, 3 % at worst, where the page shows
#: each sphere at about twice this size anyway).
SPHERE_SIZE = 112
SPHERE_QUADRATURE = (35, (0.005, 0.03, 0.12, 0.4), 25)


def sphere_images(table: Array, albedo: Mapping[str, Any] | None = None
                  ) -> tuple[list[tuple[str, Array, Array | None]], Array, Array]:
    """The spheres' renders (title, linear radiance, background or None: the environment's backdrop), the
    backdrop, and the sphere's coverage (numpy only; it may run in a second thread while the run goes on).
    ``albedo``: the plausibility check's directional albedo of the table (``theta_i_deg``, ``albedo`` (n, C)),
    by reciprocity its albedo at each view angle, which the point-light spheres' dim uniform environment
    needs (interpolated in cos theta, held beyond its last angle); integrated here when None."""
    from reconstruction.core.render import (
        PRESETS,
        Lighting,
        PointLight,
        Quadrature,
        SkyGround,
        render_sphere,
        sphere_coverage,
        sphere_normals,
    )
    from reconstruction.report.preview import AMBIENT, PREVIEW_RADIUS, albedo_at_view

    lookup = merltable.brdf_of(table)

    def brdf(wi: Array, wo: Array) -> Array:  # the table's lookup without its sparse operators (render_sphere):
        return lookup(wi, wo)  # one render each, evaluated directly (the environment once per view angle)

    size, radius = SPHERE_SIZE, PREVIEW_RADIUS
    quad = Quadrature(SPHERE_QUADRATURE[0], SPHERE_QUADRATURE[1], SPHERE_QUADRATURE[2])
    cov = sphere_coverage(size, radius, antialias=True)
    mask, n = sphere_normals(size, radius, antialias=True)
    ambient = np.zeros((size, size, 3))  # the preview's uniform environment, shared by the three point lights
    if albedo is None:
        at_view = albedo_at_view(brdf, n[:, 2])
    else:
        cos_t = np.cos(np.radians(np.asarray(albedo["theta_i_deg"], dtype=np.float64)))[::-1]  # increasing
        alb = np.asarray(albedo["albedo"], dtype=np.float64)[::-1]
        alb = np.repeat(alb, 3, axis=1) if alb.shape[1] == 1 else alb
        at_view = np.stack([np.interp(n[:, 2], cos_t, alb[:, k]) for k in range(3)], axis=-1)
    ambient[mask] = AMBIENT * at_view * cov[mask][:, None]
    uniform = np.full((size, size, 3), AMBIENT) * (1.0 - cov)[..., None]  # ... seen behind the sphere
    imgs: list[tuple[str, Array, Array | None]] = [
        (f"point light, {name}", _rgb(render_sphere(brdf, size, Lighting(points=(PointLight(pos, float(
            np.dot(pos, pos))),)), radius, antialias=True)) + ambient, uniform) for name, pos in LIGHTS.items()]
    env = _rgb(render_sphere(brdf, size, Lighting(SkyGround()), radius, antialias=True, quadrature=quad))  # once
    imgs.append(("sky and ground environment", env, None))
    for key, label in (("key", "environment + key sun (front)"), ("rim", "environment + rim sun (behind)")):
        sun = _rgb(render_sphere(brdf, size, Lighting(suns=PRESETS[key].suns), radius, antialias=True))
        imgs.append((label, env + sun, None))
    backdrop = _backdrop(size, radius, SkyGround()) / SkyGround().zenith  # display values: sky at 0.35
    return imgs, backdrop, cov


def sphere_pngs(images: tuple[list[tuple[str, Array, Array | None]], Array, Array]) -> list[tuple[str, str]]:
    """The spheres of :func:`sphere_images` as (title, PNG data URI), each exposed on its own 99.5th percentile
    on the sphere (as the preview) over its background, sRGB: written directly (no matplotlib)."""
    from reconstruction.report.preview import png_bytes, srgb_encode

    imgs, backdrop, cov = images
    out = []
    for name, im, bg in imgs:
        lum = (im @ np.array([0.2126, 0.7152, 0.0722]))[cov > 0.5]  # exposed on the sphere, as the preview
        p = float(np.percentile(lum[lum > 0], 99.5)) if np.any(lum > 0) else 1.0
        e = 1.0 / p if p > 0 else 1.0
        px = np.round(srgb_encode(im * e + (bg * e if bg is not None else backdrop)) * 255.0).astype(np.uint8)
        out.append((name, "data:image/png;base64," + base64.b64encode(png_bytes(px, level=1)).decode("ascii")))
    return out


N_DIRS = SPHERE_QUADRATURE[0] + len(SPHERE_QUADRATURE[1]) * SPHERE_QUADRATURE[2]
