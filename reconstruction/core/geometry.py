"""Direction geometry: spherical angles, in-plane samples, Rusinkiewicz half/difference angles.

Conventions (see README): the local frame has z along the surface normal. ``theta`` is the polar angle
from the normal, ``phi`` the azimuth from +x towards +y. All functions here take radians and unit vectors
and broadcast over any batch shape; direction arrays have a trailing axis of length 3.

An in-plane sample (theta_i, theta_o) puts the light on the -x side and a positive, signed theta_o on the
specular (+x) side, so theta_o = theta_i is the mirror direction and theta_o = -theta_i the retro direction.

The thesis (Tramontina 2023) calls the elevation above the surface "phi" and the azimuth "theta"; only
:func:`thesis_to_vec` and :func:`vec_to_thesis` speak that language.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike, NDArray

Array = NDArray[np.float64]

__all__ = [
    "sph_to_vec",
    "vec_to_sph",
    "normalize",
    "safe_acos",
    "inplane_to_dirs",
    "tilted_to_dirs",
    "dirs_to_inplane",
    "half_diff_from_dirs",
    "dirs_from_half_diff",
    "rotate_z",
    "rotate_y",
    "rodrigues",
    "thesis_to_vec",
    "vec_to_thesis",
    "thesis_points_from_slice",
    "slice_from_thesis_points",
]


def safe_acos(x: ArrayLike) -> Array:
    """arccos clipped to [-1, 1], so 1 + eps from rounding gives 0, not NaN.

    Examples
    --------
    >>> float(safe_acos(1.0 + 1e-12))  # rounding above 1 gives 0, not NaN
    0.0
    """
    return np.arccos(np.clip(np.asarray(x, dtype=np.float64), -1.0, 1.0))


def normalize(v: ArrayLike) -> Array:
    """Unit vectors along ``v`` (..., 3); zero vectors stay zero instead of becoming NaN.

    Examples
    --------
    >>> normalize([3.0, 0.0, 4.0]).tolist()
    [0.6, 0.0, 0.8]
    >>> normalize([0.0, 0.0, 0.0]).tolist()
    [0.0, 0.0, 0.0]
    """
    v = np.asarray(v, dtype=np.float64)
    n = np.linalg.norm(v, axis=-1, keepdims=True)
    return np.divide(v, n, out=np.zeros_like(v), where=n > 0)


def sph_to_vec(theta: ArrayLike, phi: ArrayLike) -> Array:
    """Unit vector(s) (..., 3) from polar angle ``theta`` and azimuth ``phi`` (radians).

    Examples
    --------
    >>> sph_to_vec(np.pi / 2, 0.0).round(12).tolist()  # on the horizon towards +x
    [1.0, 0.0, 0.0]
    >>> sph_to_vec([0.0, np.pi / 2], [0.0, np.pi / 2]).round(12).tolist()
    [[0.0, 0.0, 1.0], [0.0, 1.0, 0.0]]
    """
    theta = np.asarray(theta, dtype=np.float64)
    phi = np.asarray(phi, dtype=np.float64)
    st = np.sin(theta)
    return np.stack(np.broadcast_arrays(st * np.cos(phi), st * np.sin(phi), np.cos(theta)), axis=-1)


def vec_to_sph(v: ArrayLike) -> tuple[Array, Array]:
    """(theta, phi) in radians of direction(s) ``v`` (..., 3); phi in (-pi, pi], 0 at the pole.

    Uses atan2 of the in-plane radius and z, which is accurate near the pole (unlike acos).

    Examples
    --------
    >>> theta, phi = vec_to_sph([0.0, 1.0, 1.0])
    >>> round(float(np.degrees(theta)), 6), round(float(np.degrees(phi)), 6)
    (45.0, 90.0)
    """
    v = np.asarray(v, dtype=np.float64)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    theta = np.arctan2(np.hypot(x, y), z)
    phi = np.arctan2(y, x)
    return theta, phi


def inplane_to_dirs(theta_i: ArrayLike, theta_o: ArrayLike) -> tuple[Array, Array]:
    """(wi, wo) unit vectors for in-plane samples; radians, signed theta_o (+ = specular side).

    wi = (-sin theta_i, 0, cos theta_i) points to the light; wo = (sin theta_o, 0, cos theta_o).

    Examples
    --------
    >>> wi, wo = inplane_to_dirs(np.radians(30.0), np.radians(30.0))  # the mirror direction
    >>> wi.round(4).tolist(), wo.round(4).tolist()
    ([-0.5, 0.0, 0.866], [0.5, 0.0, 0.866])
    """
    ti = np.asarray(theta_i, dtype=np.float64)
    to = np.asarray(theta_o, dtype=np.float64)
    ti, to = np.broadcast_arrays(ti, to)
    zero = np.zeros_like(ti)
    wi = np.stack([-np.sin(ti), zero, np.cos(ti)], axis=-1)
    wo = np.stack([np.sin(to), zero, np.cos(to)], axis=-1)
    return wi, wo


def tilted_to_dirs(arm_i: ArrayLike, arm_o: ArrayLike, tilt: ArrayLike) -> tuple[Array, Array]:
    """(wi, wo) unit vectors in the sample's frame for a bench whose arms sit at ``arm_i`` (the light, on the -x
    side) and ``arm_o`` (the detector, signed as theta_o: + on the specular side) in its plane while the sample is
    tilted by ``tilt`` about the axis in that plane (radians):

        wi = (-sin a, cos a sin t, cos a cos t),  wo = (sin b, cos b sin t, cos b cos t).

    ``tilt`` = 0 is :func:`inplane_to_dirs`.

    Examples
    --------
    >>> wi, wo = tilted_to_dirs(np.radians(40.0), np.radians(40.0), np.radians(30.0))
    >>> wi.round(4).tolist(), wo.round(4).tolist()
    ([-0.6428, 0.383, 0.6634], [0.6428, 0.383, 0.6634])
    """
    a, b, t = np.broadcast_arrays(*(np.asarray(x, dtype=np.float64) for x in (arm_i, arm_o, tilt)))
    wi = np.stack([-np.sin(a), np.cos(a) * np.sin(t), np.cos(a) * np.cos(t)], axis=-1)
    wo = np.stack([np.sin(b), np.cos(b) * np.sin(t), np.cos(b) * np.cos(t)], axis=-1)
    return wi, wo


def dirs_to_inplane(wi: ArrayLike, wo: ArrayLike) -> tuple[Array, Array]:
    """Inverse of :func:`inplane_to_dirs` for directions in the x-z plane: (theta_i, signed theta_o).

    Examples
    --------
    >>> wi, wo = inplane_to_dirs(np.radians(30.0), np.radians(-10.0))
    >>> np.degrees(dirs_to_inplane(wi, wo)).round(9).tolist()
    [30.0, -10.0]
    """
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    return np.arctan2(-wi[..., 0], wi[..., 2]), np.arctan2(wo[..., 0], wo[..., 2])


def rotate_z(v: Array, angle: ArrayLike) -> Array:
    """Rotate vectors (..., 3) by ``angle`` (radians) about +z (counter-clockwise seen from +z).

    Examples
    --------
    >>> rotate_z(np.array([1.0, 0.0, 0.0]), np.pi / 2).round(12).tolist()
    [0.0, 1.0, 0.0]
    """
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x - s * y, s * x + c * y, z), axis=-1)


def rotate_y(v: Array, angle: ArrayLike) -> Array:
    """Rotate vectors (..., 3) by ``angle`` (radians) about +y (right-handed).

    Examples
    --------
    >>> rotate_y(np.array([0.0, 0.0, 1.0]), np.pi / 2).round(12).tolist()
    [1.0, 0.0, 0.0]
    """
    c, s = np.cos(angle), np.sin(angle)
    x, y, z = v[..., 0], v[..., 1], v[..., 2]
    return np.stack(np.broadcast_arrays(c * x + s * z, y, -s * x + c * z), axis=-1)


def rodrigues(v: ArrayLike, k: ArrayLike, angle: ArrayLike) -> Array:
    """Rotate vectors ``v`` (..., 3) about unit axis ``k`` (..., 3) by ``angle`` (radians), counter-clockwise.

    v_rot = v cos a + (k x v) sin a + k (k . v)(1 - cos a)   (Rodrigues 1840).

    Examples
    --------
    >>> rodrigues([1.0, 0.0, 0.0], [0.0, 0.0, 1.0], np.pi / 2).round(12).tolist()
    [0.0, 1.0, 0.0]
    """
    v = np.asarray(v, dtype=np.float64)
    k = normalize(k)
    a = np.asarray(angle, dtype=np.float64)[..., None]
    c, s = np.cos(a), np.sin(a)
    kv = np.sum(k * v, axis=-1, keepdims=True)
    return v * c + np.cross(k, v) * s + k * kv * (1.0 - c)


def half_diff_from_dirs(wi: ArrayLike, wo: ArrayLike) -> tuple[Array, Array, Array, Array]:
    """Rusinkiewicz (1998) angles (theta_h, phi_h, theta_d, phi_d), radians, of direction pairs (..., 3).

    h = normalize(wi + wo); d = wi rotated by -phi_h about z, then by -theta_h about y.
    Finite for normal incidence and theta_h = 0; for wi = -wo (h undefined) h is taken as the normal.

    Examples
    --------
    >>> wi, wo = inplane_to_dirs(np.radians(30.0), np.radians(30.0))
    >>> theta_h, phi_h, theta_d, phi_d = half_diff_from_dirs(wi, wo)
    >>> [round(float(np.degrees(a)), 6) for a in (theta_h, theta_d)]  # at the mirror direction theta_h = 0
    [0.0, 30.0]
    """
    wi = normalize(wi)
    wo = normalize(wo)
    h = wi + wo
    n = np.linalg.norm(h, axis=-1, keepdims=True)
    degenerate = n[..., 0] < 1e-12
    h = np.divide(h, n, out=np.zeros_like(h), where=n > 1e-12)
    h[degenerate] = (0.0, 0.0, 1.0)
    theta_h, phi_h = vec_to_sph(h)
    d = rotate_y(rotate_z(wi, -phi_h), -theta_h)
    theta_d, phi_d = vec_to_sph(d)
    return theta_h, phi_h, theta_d, phi_d


def dirs_from_half_diff(
    theta_h: ArrayLike, phi_h: ArrayLike, theta_d: ArrayLike, phi_d: ArrayLike
) -> tuple[Array, Array]:
    """Inverse of :func:`half_diff_from_dirs`: (wi, wo) unit vectors (..., 3) from radians.

    Examples
    --------
    >>> wi, wo = dirs_from_half_diff(0.0, 0.0, np.radians(30.0), np.pi)
    >>> wi.round(4).tolist(), (wo.round(4) + 0.0).tolist()
    ([-0.5, 0.0, 0.866], [0.5, 0.0, 0.866])
    """
    th, ph, td, pd = (np.asarray(a, dtype=np.float64) for a in (theta_h, phi_h, theta_d, phi_d))
    shape = np.broadcast_shapes(th.shape, ph.shape, td.shape, pd.shape)
    sth, cth, sph, cph, std, ctd = np.sin(th), np.cos(th), np.sin(ph), np.cos(ph), np.sin(td), np.cos(td)
    # d = (sin td cos pd, sin td sin pd, cos td), rotated by theta_h about y, then by phi_h about z (closed form)
    dx, dy = std * np.cos(pd), std * np.sin(pd)
    xr = cth * dx + sth * ctd
    wi = np.empty(shape + (3,))
    wo = np.empty(shape + (3,))
    wi[..., 0] = cph * xr - sph * dy
    wi[..., 1] = sph * xr + cph * dy
    wi[..., 2] = cth * ctd - sth * dx
    # wo is wi reflected about h = (sin th cos ph, sin th sin ph, cos th): wo = 2 (wi . h) h - wi, wi . h = cos td
    k = 2.0 * ctd
    wo[..., 0] = k * sth * cph - wi[..., 0]
    wo[..., 1] = k * sth * sph - wi[..., 1]
    wo[..., 2] = k * cth - wi[..., 2]
    return wi, wo


# --- the thesis's language -------------------------------------------------------------------------------


def thesis_to_vec(elevation: ArrayLike, azimuth: ArrayLike, intensity: ArrayLike = 1.0) -> Array:
    """Thesis point (elevation "phi" above the surface, azimuth "theta", intensity) -> vector (..., 3).

    Angles in radians; the result has length ``intensity``. Elevation = pi/2 - our theta.

    Examples
    --------
    >>> thesis_to_vec(np.pi / 2, 0.0, 2.0).round(12).tolist()  # elevation 90 deg: the normal, length 2
    [0.0, 0.0, 2.0]
    """
    v = sph_to_vec(np.pi / 2 - np.asarray(elevation, dtype=np.float64), azimuth)
    return v * np.asarray(intensity, dtype=np.float64)[..., None]


def vec_to_thesis(p: ArrayLike) -> tuple[Array, Array, Array]:
    """Vector(s) (..., 3) -> thesis (elevation, azimuth, intensity); angles in radians.

    Examples
    --------
    >>> [round(float(x), 6) for x in vec_to_thesis([0.0, 0.0, 2.0])]
    [1.570796, 0.0, 2.0]
    """
    p = np.asarray(p, dtype=np.float64)
    r = np.linalg.norm(p, axis=-1)
    theta, phi = vec_to_sph(p)
    return np.pi / 2 - theta, phi, r


def thesis_points_from_slice(theta_o: ArrayLike, value: ArrayLike) -> Array:
    """In-plane slice -> the thesis's ordered 2D polar curve, points (N, 2) as (x, z).

    Each point is ``value`` times the outgoing direction in the plane of incidence (x to the specular side).

    Examples
    --------
    >>> thesis_points_from_slice(np.radians([-30.0, 0.0, 30.0]), [1.0, 2.0, 1.0]).round(4).tolist()
    [[-0.5, 0.866], [0.0, 2.0], [0.5, 0.866]]
    """
    to = np.asarray(theta_o, dtype=np.float64)
    val = np.asarray(value, dtype=np.float64)
    return np.stack([val * np.sin(to), val * np.cos(to)], axis=-1)


def slice_from_thesis_points(points: ArrayLike) -> tuple[Array, Array]:
    """Inverse of :func:`thesis_points_from_slice`: (signed theta_o in radians, value) of 2D points (N, 2).

    Examples
    --------
    >>> theta_o, value = slice_from_thesis_points([[-0.5, 0.8660254], [0.0, 2.0]])
    >>> np.degrees(theta_o).round(4).tolist(), value.round(6).tolist()
    ([-30.0, 0.0], [1.0, 2.0])
    """
    p = np.asarray(points, dtype=np.float64)
    return np.arctan2(p[..., 0], p[..., 1]), np.hypot(p[..., 0], p[..., 1])
