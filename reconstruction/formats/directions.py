"""Rows out of the plane of incidence in CSV inputs: a tilt column, or each sample's azimuths.

An in-plane bench gives (theta_i, signed theta_o) pairs. Two optional columns place a row anywhere on the
hemisphere, in a generic table and (the tilt) in a slice file (docs/formats.md):

* ``tilt_deg`` (or ``tilt``): the sample tilted by t about the axis in the arms' plane; theta_i and theta_o are then
  the arm angles a (the light, on the -x side) and b (the detector, signed + on the specular side), and in the
  sample's frame the light is (-sin a, cos a sin t, cos a cos t) and the detector (sin b, cos b sin t, cos b cos t)
  (:func:`reconstruction.core.geometry.tilted_to_dirs`); t = 0 is an in-plane row;
* ``phi_i_deg`` and ``phi_o_deg`` (or ``phi_i``, ``phi_o``): azimuths of the light and the detector; theta_i and
  theta_o are then their polar angles (0-90 deg, theta_o not signed): w = (sin theta cos phi, sin theta sin phi,
  cos theta). An in-plane slice's row (theta_i, theta_o) is phi_i = 180, phi_o = 0 (theta_o >= 0) or 180.

Such a file is read as :class:`RowsWithDirections` (every row with its directions; the file's angle columns kept
for the blind-spot rule) and handed to the methods as a
:class:`~reconstruction.core.samples.SliceWithPoints` (:func:`as_points`): the rows in the plane of incidence as
the slice that in-plane methods (revolve, bivariate's lines) read, every row as points placed by their directions
(fit, microfacet, prior, bivariate's grid), as Zemax and RGL files' points are.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.core.geometry import tilted_to_dirs
from reconstruction.core.samples import SliceWithPoints, directional_slice, out_of_plane
from reconstruction.core.slicedata import Slice, SliceError

Array = NDArray[np.float64]

__all__ = ["TILT_NAMES", "PHI_I_NAMES", "PHI_O_NAMES", "role_of", "RowsWithDirections", "with_directions",
           "same_rows", "row_keys", "as_points"]

TILT_NAMES = ("tilt_deg", "tilt")
PHI_I_NAMES = ("phi_i_deg", "phi_i")
PHI_O_NAMES = ("phi_o_deg", "phi_o")


def role_of(name: str) -> str | None:
    """"tilt", "phi_i" or "phi_o" for a direction column's name (any letter case), else None."""
    low = name.strip().lower()
    return next((r for r, names in (("tilt", TILT_NAMES), ("phi_i", PHI_I_NAMES), ("phi_o", PHI_O_NAMES))
                 if low in names), None)


@dataclass
class RowsWithDirections(Slice):
    """Every row of a file with direction columns: ``theta_i_deg``/``theta_o_deg`` as the file gives them (arm
    angles, or polar angles), ``wi``/``wo`` (N, 3) each row's unit directions in the sample's frame."""

    wi: Array = field(default_factory=lambda: np.zeros((0, 3)))
    wo: Array = field(default_factory=lambda: np.zeros((0, 3)))

    def take(self, idx: ArrayLike) -> RowsWithDirections:
        idx = np.asarray(idx)
        return same_rows(self, Slice.take(self, idx), self.wi[idx], self.wo[idx])  # type: ignore[return-value]

    def brdf(self) -> tuple[Array, Array]:
        """(f_r, its std) (N, C): ``brdf_cos`` divided by the cosine of the detector's true polar angle."""
        if self.quantity != "brdf_cos":
            return Slice.brdf(self)
        c = np.maximum(self.wo[:, 2], 1e-6)[:, None]
        assert self.std is not None
        return self.values / c, self.std / c


def same_rows(like: Slice, s: Slice, wi: Array | None = None, wo: Array | None = None) -> Slice:
    """``s`` (the rows of ``like``, new values or metadata) with ``like``'s directions when it has them."""
    if not isinstance(like, RowsWithDirections):
        return s
    return RowsWithDirections(s.theta_i_deg, s.theta_o_deg, s.values, list(s.channels), s.std, s.repeats,
                              s.unix_time_s, s.meta, s.source, like.wi if wi is None else wi,
                              like.wo if wo is None else wo)


def with_directions(s: Slice, cols: dict[str, Array], where: str, line_of: ArrayLike | None = None) -> Slice:
    """The rows of ``s`` (angles in degrees) placed by the direction columns ``cols`` ({"tilt": (N,)} or
    {"phi_i": (N,), "phi_o": (N,)}, degrees); ``s`` itself without any. :class:`SliceError` naming ``where`` (the
    file) and the line (``line_of``: each row's line) for a bad combination or value."""
    if not cols:
        return s
    lines = np.asarray(line_of) if line_of is not None else np.arange(len(s)) + 1
    if "tilt" in cols and ("phi_i" in cols or "phi_o" in cols):
        raise SliceError(f"{where}: both a tilt column and azimuth columns; give the arm angles with tilt_deg, or "
                         "the polar angles with phi_i_deg and phi_o_deg")
    if "tilt" in cols:
        t = np.asarray(cols["tilt"], dtype=np.float64)
        bad = ~np.isfinite(t) | (np.abs(t) >= 90.0)
        if bad.any():
            r = int(np.argmax(bad))
            raise SliceError(f"{where}:{lines[r]}, column tilt_deg: {t[r]} is outside (-90, 90) degrees")
        wi, wo = tilted_to_dirs(np.radians(s.theta_i_deg), np.radians(s.theta_o_deg), np.radians(t))
    else:
        if "phi_i" not in cols or "phi_o" not in cols:
            raise SliceError(f"{where}: an azimuth column needs the other (phi_i_deg and phi_o_deg)")
        neg = (s.theta_i_deg < 0) | (s.theta_o_deg < 0)
        if neg.any():
            r = int(np.argmax(neg))
            raise SliceError(f"{where}:{lines[r]}: with azimuth columns theta_i and theta_o are polar angles in "
                             f"[0, 90) degrees, got {s.theta_i_deg[r]:g}, {s.theta_o_deg[r]:g}")
        ti, to = np.radians(s.theta_i_deg), np.radians(s.theta_o_deg)
        pi_, po = np.radians(cols["phi_i"]), np.radians(cols["phi_o"])
        wi = np.stack([np.sin(ti) * np.cos(pi_), np.sin(ti) * np.sin(pi_), np.cos(ti)], axis=-1)
        wo = np.stack([np.sin(to) * np.cos(po), np.sin(to) * np.sin(po), np.cos(to)], axis=-1)
    if not (np.isfinite(wi).all() and np.isfinite(wo).all()):
        r = int(np.argmax(~np.isfinite(wi).all(axis=1) | ~np.isfinite(wo).all(axis=1)))
        raise SliceError(f"{where}:{lines[r]}: an azimuth is not a finite number")
    return RowsWithDirections(s.theta_i_deg, s.theta_o_deg, s.values, list(s.channels), s.std, s.repeats,
                              s.unix_time_s, s.meta, s.source, wi, wo)


def row_keys(s: Slice) -> Array:
    """(N, k) what makes a row a distinct sample: (theta_i, theta_o), and its directions for rows that have them."""
    key = np.stack([s.theta_i_deg, s.theta_o_deg], axis=1)
    if isinstance(s, RowsWithDirections):
        return np.concatenate([key, np.round(np.c_[s.wi, s.wo], 9)], axis=1)
    wi, wo = sample_dirs_inplane(s)
    return np.concatenate([key, np.round(np.c_[wi, wo], 9)], axis=1)


def sample_dirs_inplane(s: Slice) -> tuple[Array, Array]:
    """(wi, wo) of in-plane rows (radians inside)."""
    from reconstruction.core.geometry import inplane_to_dirs

    return inplane_to_dirs(np.radians(s.theta_i_deg), np.radians(s.theta_o_deg))


def as_points(merged: Slice, parts: list[Slice]) -> Slice:
    """``merged`` (the rows of ``parts`` in order, f_r) as the methods read it: a
    :class:`~reconstruction.core.samples.SliceWithPoints` of the rows in the plane of incidence (each once, as
    (theta_i, signed theta_o)) with every row as points when any part has directions, else ``merged`` itself."""
    if not any(isinstance(p, RowsWithDirections) for p in parts):
        return merged
    dirs = [(p.wi, p.wo) if isinstance(p, RowsWithDirections) else sample_dirs_inplane(p) for p in parts]
    wi, wo = np.concatenate([d[0] for d in dirs]), np.concatenate([d[1] for d in dirs])
    pts = directional_slice(wi, wo, merged.values, list(merged.channels), meta=dict(merged.meta),
                            source=merged.source)
    assert merged.std is not None
    pts.std, pts.repeats, pts.unix_time_s = merged.std, merged.repeats, merged.unix_time_s
    inplane = np.nonzero(~out_of_plane(pts) & (wi[:, 2] > 0) & (wo[:, 2] > 0))[0]
    if inplane.size == 0:
        raise SliceError(f"{merged.source}: no row lies in the plane of incidence (tilt 0, or azimuths 180 deg "
                         "apart); the in-plane methods need at least one in-plane sweep")
    _, first = np.unique(np.round(np.c_[pts.theta_i_deg[inplane], pts.theta_o_deg[inplane]], 6), axis=0,
                         return_index=True)
    base = Slice.take(pts, inplane[np.sort(first)])
    return SliceWithPoints(base.theta_i_deg, base.theta_o_deg, base.values, base.channels, base.std, base.repeats,
                           base.unix_time_s, dict(merged.meta), merged.source, pts)
