"""Zemax tabular BSDF files (the Radiant Imaging "BSDF Data Interchange" text format): read and write.

OpticStudio, Radiant imaging spheres and Ansys Speos converters exchange these ``.bsdf`` files::

    #comment lines start with #
    Source  Measured
    Symmetry  PlaneSymmetrical          (or Asymmetrical, ASymmetrical4D)
    SpectralContent  Monochrome         (or XYZ)
    ScatterType  BRDF                   (BTDF: transmission, not read here)
    SampleRotation  1
    0
    AngleOfIncidence  4
    0 22.5 45 67.5
    ScatterAzimuth  37
    0 5 10 ... 180
    ScatterRadial  31
    0 0.5 1 ... 90

    Monochrome                          (XYZ files: TristimulusX, then TristimulusY, TristimulusZ sections)
    DataBegin
    TIS 0.134                           (per sample rotation and incidence: the TIS line, then one line per
    6.375E-02 6.180E-02 ...              azimuth with one BRDF value, 1/sr, per radial angle)
    ...
    DataEnd

Angles in degrees. ``AngleOfIncidence`` is the polar angle of the incident (equally, of the specular) direction.
A scatter direction is given about the specular direction: ``ScatterRadial`` r is its angle from the specular
direction (on the sphere), ``ScatterAzimuth`` a the azimuth about it, 0 pointing from the specular direction
towards the surface normal (in the plane of incidence), counter-clockwise seen from the specular direction. In
our frame (light on the -x side, wi = (-sin t, 0, cos t)) the specular direction is s = (sin t, 0, cos t), the
azimuth-0 tangent e1 = (-cos t, 0, sin t), e2 = s x e1 = (0, -1, 0), and the direction is
d = cos r s + sin r (cos a e1 + sin a e2): azimuth 0 is the in-plane side between the mirror direction and the
retro direction (signed theta_o = t - r), azimuth 180 the grazing side (theta_o = t + r). We checked this reading
on a real converted file (benchmarks/bench_formats.py): its values are exactly zero where d is below the horizon
and positive above it, for every azimuth.

``PlaneSymmetrical`` files give azimuths 0-180 only (the other half mirrors them), ``Asymmetrical`` 0-360 with
one sample rotation, ``ASymmetrical4D`` several sample rotations: read here for isotropic use (the rotations are
averaged; the spread between them is reported). ``XYZ`` tristimulus values are converted to linear sRGB (IEC
61966-2-1 matrix). :func:`write` writes a reconstruction on a stated grid (``PlaneSymmetrical``, the isotropic
form), ``TIS`` per incidence = the directional albedo of the written values.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.atomic import atomic_open
from reconstruction.base import ReconstructionError
from reconstruction.core.samples import SliceWithPoints, directional_slice
from reconstruction.formats.inputs import LoadedInput, check_whole_file_input

Array = NDArray[np.float64]
BRDF = Callable[[Array, Array], ArrayLike]

__all__ = ["ZemaxError", "ZemaxBSDF", "is_zemax", "read", "write", "tabulate", "DEFAULT_INCIDENCES_DEG",
           "DEFAULT_AZIMUTHS_DEG", "DEFAULT_RADIALS_DEG", "scatter_directions", "parse_angle_list",
           "XYZ_TO_RGB", "RGB_TO_XYZ"]

HEADER_KEYS = ("Source", "Symmetry", "SpectralContent", "ScatterType", "SampleRotation", "AngleOfIncidence",
               "ScatterAzimuth", "ScatterRadial")
SYMMETRIES = {"planesymmetrical": "PlaneSymmetrical", "asymmetrical": "Asymmetrical",
              "asymmetrical4d": "ASymmetrical4D"}
#: linear sRGB (D65) <-> CIE XYZ, IEC 61966-2-1
RGB_TO_XYZ = np.array([[0.4124, 0.3576, 0.1805], [0.2126, 0.7152, 0.0722], [0.0193, 0.1192, 0.9505]])
XYZ_TO_RGB = np.linalg.inv(RGB_TO_XYZ)

#: the default output grid: incidences every 5 deg to 50 and every 2.5 deg from 50 to 87.5 (a reader interpolates
#: between incidences at a fixed azimuth and radial angle, which a lobe near grazing outruns: every 10 deg to 80
#: left 19 % relative RMSE of f cos cos on a ggx alpha 0.15 lobe, this grid 1.8 %; benchmarks/bench_zemax_real.py),
#: azimuths 0-180 every 5 (plane-symmetric), radial angles fine near the specular direction (0.25 deg) and every 5
#: deg beyond 20 deg, to 180
DEFAULT_INCIDENCES_DEG = np.concatenate([np.arange(0.0, 50.0, 5.0), np.arange(50.0, 88.0, 2.5)])
DEFAULT_AZIMUTHS_DEG = np.arange(0.0, 181.0, 5.0)
DEFAULT_RADIALS_DEG = np.concatenate([[0.0, 0.25, 0.5, 0.75, 1.0, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.0, 8.0, 9.0],
                                      np.arange(10.0, 20.0, 2.0), np.arange(20.0, 181.0, 5.0)])


class ZemaxError(ReconstructionError):
    """A Zemax file cannot be read or written; the message names the file, line and what was expected."""


@dataclass
class ZemaxBSDF:
    """The contents of a Zemax tabular BSDF file.

    ``values`` (C, R, I, A, N): BRDF in 1/sr per channel, sample rotation, incidence, azimuth and radial angle;
    ``tis`` (C, R, I) the file's TIS lines. Angles in degrees. ``channels``: ["value"] or ["X", "Y", "Z"].
    """

    symmetry: str
    spectral_content: str
    scatter_type: str
    sample_rotation_deg: Array
    incidence_deg: Array
    azimuth_deg: Array
    radial_deg: Array
    values: Array
    tis: Array
    channels: list[str]
    source: str = "<memory>"
    comments: list[str] = field(default_factory=list)

    def full_azimuths(self) -> tuple[Array, Array]:
        """(azimuths, values (C, R, I, A', N)) over 0-360: plane-symmetric data mirrored (a -> 360 - a)."""
        az, v = self.azimuth_deg, self.values
        if self.symmetry != "PlaneSymmetrical":
            return az, v
        extra = (az > 0) & (az < 180)
        mirrored = 360.0 - az[extra][::-1]
        return np.concatenate([az, mirrored]), np.concatenate([v, v[..., extra, :][..., ::-1, :]], axis=-2)

    def isotropic(self) -> tuple[Array, Array]:
        """(values (C, I, A, N) averaged over sample rotations, relative spread between rotations)."""
        v = self.values.mean(axis=1)
        if self.values.shape[1] == 1:
            return v, np.zeros(1)
        spread = np.abs(self.values - v[:, None]).max() / max(float(np.abs(v).max()), 1e-300)
        return v, np.array([spread])

    def rgb_values(self) -> tuple[Array, list[str]]:
        """(values (C', I, A, N), channels): grey stays grey, XYZ becomes linear sRGB; rotations averaged."""
        v, _ = self.isotropic()
        if self.channels == ["X", "Y", "Z"]:
            return np.einsum("rc,c...->r...", XYZ_TO_RGB, v), ["R", "G", "B"]
        return v, ["value"]


# --- geometry --------------------------------------------------------------------------------------------


def scatter_directions(incidence_deg: ArrayLike, azimuth_deg: ArrayLike, radial_deg: ArrayLike
                       ) -> tuple[Array, Array]:
    """(wi, wo) unit vectors (..., 3) of Zemax angles (degrees, broadcast together), in our frame (module doc)."""
    t, a, r = (np.radians(np.asarray(x, dtype=np.float64)) for x in (incidence_deg, azimuth_deg, radial_deg))
    t, a, r = np.broadcast_arrays(t, a, r)
    st, ct = np.sin(t), np.cos(t)
    sr, cr, ca, sa = np.sin(r), np.cos(r), np.cos(a), np.sin(a)
    wo = np.stack([cr * st - sr * ca * ct, -sr * sa, cr * ct + sr * ca * st], axis=-1)
    wi = np.stack([-st, np.zeros_like(st), ct], axis=-1)
    return wi, wo


def zemax_angles(wi: ArrayLike, wo: ArrayLike) -> tuple[Array, Array, Array]:
    """Inverse of :func:`scatter_directions` for wi in the x-z plane: (incidence, azimuth 0-360, radial), deg."""
    wi = np.asarray(wi, dtype=np.float64)
    wo = np.asarray(wo, dtype=np.float64)
    t = np.arctan2(-wi[..., 0], wi[..., 2])
    st, ct = np.sin(t), np.cos(t)
    zs = wo[..., 0] * st + wo[..., 2] * ct  # component along s
    z1 = -wo[..., 0] * ct + wo[..., 2] * st  # along e1
    z2 = -wo[..., 1]  # along e2
    r = np.arctan2(np.hypot(z1, z2), zs)
    a = np.mod(np.arctan2(z2, z1), 2 * np.pi)
    return np.degrees(t), np.degrees(a), np.degrees(r)


# --- reading ---------------------------------------------------------------------------------------------


def is_zemax(path: str | Path) -> bool:
    """True if the file's first line that is neither blank nor a # comment is a Zemax header line (``Source``
    or another header keyword). Only regular files are looked into (a pipe or a device would block)."""
    if not Path(path).is_file():
        return False
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError:
        return False
    for raw in head.decode("utf-8", "replace").splitlines():
        s = raw.strip()
        if not s or s.startswith("#"):
            continue
        word = s.split()[0].lower()
        return word in {k.lower() for k in HEADER_KEYS}
    return False


_NUMBER = re.compile(r"^[+-]?(\d+\.?\d*|\.\d+)([eE][+-]?\d+)?$")


class _Lines:
    """The file's lines with their numbers; comments and blank lines are skipped where the format allows."""

    def __init__(self, path: Path, text: str) -> None:
        self.path = path
        self.lines = text.splitlines()
        self.i = 0
        self.comments: list[str] = []

    def where(self, i: int | None = None) -> str:
        return f"{self.path}:{(self.i if i is None else i) + 1}"

    def next(self, what: str) -> tuple[int, str]:
        while self.i < len(self.lines):
            s = self.lines[self.i].strip()
            self.i += 1
            if s.startswith("#"):
                self.comments.append(s[1:].strip())
                continue
            if s:
                return self.i - 1, s
        raise ZemaxError(f"{self.path}:{len(self.lines)}: the file ends; expected {what}")


def _keyword(lines: _Lines, key: str) -> tuple[int, str]:
    i, s = lines.next(f"the {key} line")
    parts = s.split(None, 1)
    if parts[0].lower() != key.lower():
        raise ZemaxError(f"{lines.where(i)}: expected the {key} line, got {s[:60]!r}")
    if len(parts) < 2:
        raise ZemaxError(f"{lines.where(i)}: {key}: expected a value after the keyword")
    return i, parts[1].strip()


def _count(lines: _Lines, key: str) -> int:
    i, v = _keyword(lines, key)
    if not re.fullmatch(r"\d+", v) or int(v) < 1:
        raise ZemaxError(f"{lines.where(i)}: {key}: expected a positive count, got {v!r}")
    return int(v)


def _numbers(lines: _Lines, n: int, what: str) -> Array:
    """n numbers, possibly over several lines."""
    vals: list[float] = []
    first = None
    while len(vals) < n:
        i, s = lines.next(f"{n} {what}")
        first = i if first is None else first
        for tok in s.split():
            if not _NUMBER.match(tok):
                raise ZemaxError(f"{lines.where(i)}: {what}: expected a number, got {tok!r}")
            vals.append(float(tok))
    if len(vals) != n:
        raise ZemaxError(f"{lines.where(first)}: {what}: expected {n} values (the count line says so), got "
                         f"{len(vals)}")
    return np.array(vals)


def _angles(lines: _Lines, key: str, lo: float, hi: float) -> Array:
    n = _count(lines, key)
    start = lines.i
    a = _numbers(lines, n, f"{key} angles")
    if np.any(a < lo) or np.any(a > hi):
        bad = a[(a < lo) | (a > hi)][0]
        raise ZemaxError(f"{lines.where(start)}: {key}: {bad:g} deg is outside [{lo:g}, {hi:g}]")
    if n > 1 and np.any(np.diff(a) <= 0):
        raise ZemaxError(f"{lines.where(start)}: {key}: the angles must increase strictly")
    return a


def _section(lines: _Lines, label: str, n_rot: int, n_inc: int, n_az: int, n_rad: int) -> tuple[Array, Array]:
    """One DataBegin .. DataEnd section: (values (R, I, A, N), tis (R, I))."""
    i, s = lines.next(f"the {label} line")
    if s.lower() != label.lower():
        raise ZemaxError(f"{lines.where(i)}: expected {label!r} (the SpectralContent indicator), got {s[:60]!r}")
    i, s = lines.next("DataBegin")
    if s.lower() != "databegin":
        raise ZemaxError(f"{lines.where(i)}: expected DataBegin, got {s[:60]!r}")
    n_blocks = n_rot * n_inc
    rows = lines.lines
    start = lines.i
    # the block's lines: a TIS line then n_az rows; the DataEnd line after the last block
    per = n_az + 1
    stop = start + n_blocks * per
    if stop > len(rows):
        raise ZemaxError(f"{lines.where(len(rows) - 1)}: the file ends inside the data; expected {n_blocks} blocks "
                         f"(TIS line + {n_az} rows) then DataEnd")
    block = rows[start:stop]
    tis_lines = block[::per]
    tis = np.empty(n_blocks)
    for b, t in enumerate(tis_lines):  # one line per block
        parts = t.split()
        if len(parts) != 2 or parts[0] != "TIS" or not _NUMBER.match(parts[1]):
            raise ZemaxError(f"{lines.where(start + b * per)}: expected 'TIS <number>' starting block {b + 1} of "
                             f"{n_blocks} (rotation {b // n_inc + 1}, incidence {b % n_inc + 1}), got "
                             f"{t.strip()[:60]!r}")
        tis[b] = float(parts[1])
    data_rows = [r for k, r in enumerate(block) if k % per]
    counts = np.array([len(r.split()) for r in data_rows])
    if np.any(counts != n_rad):
        k = int(np.argmax(counts != n_rad))
        line = start + (k // n_az) * per + 1 + k % n_az
        raise ZemaxError(f"{lines.where(line)}: expected {n_rad} values (one per ScatterRadial angle) for azimuth "
                         f"{k % n_az + 1} of block {k // n_az + 1}, got {counts[k]}")
    try:
        vals = np.array(" ".join(data_rows).split(), dtype=np.float64)
    except ValueError:
        for k, r in enumerate(data_rows):  # find the culprit for the message
            for tok in r.split():
                if not _NUMBER.match(tok):
                    line = start + (k // n_az) * per + 1 + k % n_az
                    raise ZemaxError(f"{lines.where(line)}: expected a number, got {tok!r}") from None
        raise
    if not np.all(np.isfinite(vals)):
        k = int(np.argmax(~np.isfinite(vals))) // n_rad
        line = start + (k // n_az) * per + 1 + k % n_az
        raise ZemaxError(f"{lines.where(line)}: NaN or infinite BRDF value")
    if np.any(vals < 0):
        k = int(np.argmax(vals < 0)) // n_rad
        line = start + (k // n_az) * per + 1 + k % n_az
        raise ZemaxError(f"{lines.where(line)}: negative BRDF value {vals[vals < 0][0]:g}; expected >= 0")
    lines.i = stop
    i, s = lines.next("DataEnd")
    if s.lower() != "dataend":
        raise ZemaxError(f"{lines.where(i)}: expected DataEnd after {n_blocks} blocks of {n_az} rows, got "
                         f"{s[:60]!r} (more rows than ScatterAzimuth says?)")
    return vals.reshape(n_rot, n_inc, n_az, n_rad), tis.reshape(n_rot, n_inc)


def read(path: str | Path) -> ZemaxBSDF:
    """Read a Zemax tabular BSDF file; :class:`ZemaxError` naming file, line and what was expected."""
    path = Path(path)
    try:
        text = path.read_text(encoding="utf-8-sig", errors="strict")
    except FileNotFoundError:
        raise ZemaxError(f"{path}: no such file") from None
    except UnicodeDecodeError as e:
        raise ZemaxError(f"{path}: not a text file ({e.reason} at byte {e.start})") from None
    lines = _Lines(path, text)
    _keyword(lines, "Source")
    i, sym = _keyword(lines, "Symmetry")
    if sym.lower() not in SYMMETRIES:
        raise ZemaxError(f"{lines.where(i)}: Symmetry {sym!r}: expected PlaneSymmetrical, Asymmetrical or "
                         f"ASymmetrical4D")
    symmetry = SYMMETRIES[sym.lower()]
    i, spec = _keyword(lines, "SpectralContent")
    if spec.lower() not in ("monochrome", "xyz"):
        raise ZemaxError(f"{lines.where(i)}: SpectralContent {spec!r}: expected Monochrome or XYZ")
    spectral = "Monochrome" if spec.lower() == "monochrome" else "XYZ"
    i, st = _keyword(lines, "ScatterType")
    if st.upper() == "BTDF":
        raise ZemaxError(f"{lines.where(i)}: ScatterType BTDF: this file describes transmission; gonio-reconstruct "
                         f"reads reflection data (ScatterType BRDF) only")
    if st.upper() != "BRDF":
        raise ZemaxError(f"{lines.where(i)}: ScatterType {st!r}: expected BRDF")
    rot = _angles(lines, "SampleRotation", -360.0, 360.0)
    inc = _angles(lines, "AngleOfIncidence", 0.0, 90.0)
    az = _angles(lines, "ScatterAzimuth", 0.0, 360.0)
    rad = _angles(lines, "ScatterRadial", 0.0, 180.0)
    if symmetry == "PlaneSymmetrical" and az[-1] > 180.0:
        raise ZemaxError(f"{path}: Symmetry PlaneSymmetrical: expected azimuths within 0-180 deg, the last is "
                         f"{az[-1]:g}")
    if symmetry == "Asymmetrical" and rot.size > 1:
        raise ZemaxError(f"{path}: Symmetry Asymmetrical: expected one SampleRotation, got {rot.size} (use "
                         f"ASymmetrical4D for several)")
    labels = ["Monochrome"] if spectral == "Monochrome" else ["TristimulusX", "TristimulusY", "TristimulusZ"]
    vals, tis = [], []
    for label in labels:  # one or three sections
        v, t = _section(lines, label, rot.size, inc.size, az.size, rad.size)
        vals.append(v)
        tis.append(t)
    return ZemaxBSDF(symmetry, spectral, "BRDF", rot, inc, az, rad, np.stack(vals), np.stack(tis),
                     ["value"] if spectral == "Monochrome" else ["X", "Y", "Z"], str(path), lines.comments)


# --- to the methods --------------------------------------------------------------------------------------


def to_slices(z: ZemaxBSDF, max_theta_o_deg: float = 89.0) -> tuple[SliceWithPoints, list[str]]:
    """The in-plane slices of ``z`` (every method reads them) carrying all its points above the horizon (for
    ``fit`` and ``microfacet``), and notes for the report. Values in the file's channels (grey or linear sRGB).
    """
    vals, channels = z.rgb_values()  # (C, I, A, N)
    inc, az, rad = z.incidence_deg, z.azimuth_deg, z.radial_deg
    notes: list[str] = []
    if np.any(inc >= 90):
        notes.append("incidences at 90 deg left out (grazing: no reflection)")
    keep_i = inc < 90.0
    inc_k, vals = inc[keep_i], vals[:, keep_i]
    # in-plane: azimuth 0 gives theta_o = t - r, azimuth 180 gives theta_o = t + r (r > 0)
    az0 = np.isclose(az, 0.0) | np.isclose(az, 360.0)
    az180 = np.isclose(az, 180.0)
    if not az0.any() or not az180.any():
        raise ZemaxError(f"{z.source}: ScatterAzimuth has no {'0' if not az0.any() else '180'} deg: the plane of "
                         f"incidence (azimuths 0 and 180) is not in the file")
    v0 = vals[:, :, int(np.argmax(az0))]  # (C, I, N)
    v180 = vals[:, :, int(np.argmax(az180))]
    t = inc_k[:, None]
    to = np.concatenate([np.broadcast_to(t - rad, (t.size, rad.size)),
                         np.broadcast_to(t + rad[rad > 0], (t.size, int(np.sum(rad > 0))))], axis=1)
    v = np.concatenate([v0, v180[:, :, rad > 0]], axis=2)  # (C, I, M)
    ti = np.broadcast_to(t, to.shape)
    ok = np.abs(to) <= max_theta_o_deg
    f = np.moveaxis(v, 0, -1)[ok]
    meta = {"quantity": "brdf", "source_kind": "Zemax tabular BSDF", "symmetry": z.symmetry,
            "spectral_content": z.spectral_content}
    inplane = SliceWithPoints(ti[ok], to[ok], f, channels, meta=meta, source=z.source)
    # every point above the horizon, at the file's own grid (mirrored azimuths add nothing for isotropic data)
    wi, wo = scatter_directions(inc_k[:, None, None], az[None, :, None], rad[None, None, :])
    up = wo[..., 2] > math.cos(math.radians(max_theta_o_deg))
    pts = directional_slice(wi[up], wo[up], np.moveaxis(vals, 0, -1)[up], channels, meta=meta, source=z.source)
    inplane.points = pts
    _, spread = z.isotropic()
    notes.append(f"{z.source}: Zemax {z.symmetry} {z.spectral_content} BRDF, {z.sample_rotation_deg.size} sample "
                 f"rotation(s), incidences {', '.join(f'{x:g}' for x in inc_k)} deg, {az.size} azimuths x "
                 f"{rad.size} radial angles: {len(inplane)} in-plane samples (azimuths 0 and 180) for every method, "
                 f"{len(pts)} points above the horizon for fit and microfacet")
    if z.sample_rotation_deg.size > 1:
        notes.append(f"{z.sample_rotation_deg.size} sample rotations averaged for isotropic use (largest difference "
                     f"from their mean: {spread[0]:.1%} of the peak)")
    if z.spectral_content == "XYZ":
        notes.append("XYZ tristimulus values converted to linear sRGB (IEC 61966-2-1 matrix)")
    return inplane, notes


def file_albedo(z: ZemaxBSDF) -> Array:
    """Directional albedo (C, R, I) of the file's own values: trapezoid integral of f cos theta_o over its grid
    (azimuths 0-360, mirrored if plane-symmetric), values below the horizon left out."""
    az, v = z.full_azimuths()
    return _grid_albedo(z.incidence_deg, az, z.radial_deg, v)


def _trapezoid(x: Array) -> Array:
    """Trapezoid weights of the nodes ``x`` (n,); a single node gets weight 0."""
    if x.size < 2:
        return np.zeros(x.size)
    d = np.diff(x)
    return 0.5 * (np.concatenate([d, [0.0]]) + np.concatenate([[0.0], d]))


def _grid_albedo(inc: Array, az: Array, rad: Array, v: Array) -> Array:
    """Trapezoid integral of v cos theta_o sin r dr da over the (azimuth, radial) grid (degrees), per leading
    index of ``v`` (..., I, A, N); the azimuths are closed into a full circle."""
    a = np.radians(az)
    if a[-1] - a[0] < 2 * np.pi - 1e-9:
        a = np.concatenate([a, [a[0] + 2 * np.pi]])
        v = np.concatenate([v, v[..., :1, :]], axis=-2)
    r = np.radians(rad)
    _, wo = scatter_directions(inc[:, None, None], np.degrees(a)[None, :, None], rad[None, None, :])
    cos_o = np.clip(wo[..., 2], 0.0, None)  # (I, A, N)
    w = _trapezoid(a)[:, None] * (_trapezoid(r) * np.sin(r))[None, :]
    return np.sum(v * cos_o * w, axis=(-2, -1))


# --- writing ---------------------------------------------------------------------------------------------


def parse_angle_list(text: str, lo: float, hi: float, what: str) -> Array:
    """Angles from ``"0,10,20"`` or ranges ``"0:80:10"`` (start:stop:step, stop included), comma-separated."""
    out: list[float] = []
    for part in text.split(","):
        p = part.strip()
        if not p:
            continue
        try:
            if ":" in p:
                a, b, c = (float(x) for x in p.split(":"))
                if c <= 0 or b < a:
                    raise ValueError
                out.extend(np.arange(a, b + c * 1e-9, c).tolist())
            else:
                out.append(float(p))
        except ValueError:
            raise ZemaxError(f"{what}: expected degrees as a comma list (0,10,20) or ranges start:stop:step "
                             f"(0:80:10), got {p!r}") from None
    a = np.unique(np.round(np.asarray(out, dtype=np.float64), 9))
    if a.size == 0:
        raise ZemaxError(f"{what}: no angles in {text!r}")
    if a[0] < lo or a[-1] > hi:
        raise ZemaxError(f"{what}: angles must lie in [{lo:g}, {hi:g}] deg, got {a[0]:g} .. {a[-1]:g}")
    return a


def tabulate(f: BRDF, incidence_deg: ArrayLike = DEFAULT_INCIDENCES_DEG, azimuth_deg: ArrayLike =
             DEFAULT_AZIMUTHS_DEG, radial_deg: ArrayLike = DEFAULT_RADIALS_DEG) -> Array:
    """f (C, I, A, N) of the BRDF ``f(wi, wo) -> (M, C)`` on a Zemax grid (degrees); 0 below the horizon."""
    inc, az, rad = (np.asarray(x, dtype=np.float64) for x in (incidence_deg, azimuth_deg, radial_deg))
    wi, wo = scatter_directions(inc[:, None, None], az[None, :, None], rad[None, None, :])
    up = (wo[..., 2] > 1e-9) & (wi[..., 2] > 1e-9)
    vals = np.asarray(f(wi.reshape(-1, 3), wo.reshape(-1, 3)), dtype=np.float64).reshape(up.shape + (-1,))
    vals = np.where(up[..., None], np.maximum(np.nan_to_num(vals, nan=0.0, posinf=0.0), 0.0), 0.0)
    return np.moveaxis(vals, -1, 0)


def write(path: str | Path, f: BRDF, channels: Sequence[str], *, incidence_deg: ArrayLike = DEFAULT_INCIDENCES_DEG,
          azimuth_deg: ArrayLike = DEFAULT_AZIMUTHS_DEG, radial_deg: ArrayLike = DEFAULT_RADIALS_DEG,
          comments: Sequence[str] = ()) -> dict[str, object]:
    """Write the BRDF ``f`` (grey -> Monochrome, linear sRGB -> XYZ) as a PlaneSymmetrical Zemax BRDF file on the
    given grid (degrees; azimuths within 0-180), atomically. TIS per incidence = the directional albedo of ``f``
    (integral of f cos theta_o over the hemisphere, by quadrature; each XYZ section its own). Returns what was
    written."""
    inc, az, rad = (np.asarray(x, dtype=np.float64) for x in (incidence_deg, azimuth_deg, radial_deg))
    if az[0] != 0.0 or az[-1] != 180.0:
        raise ZemaxError(f"{path}: a PlaneSymmetrical grid needs azimuths from 0 to 180 deg, got {az[0]:g} .. "
                         f"{az[-1]:g}")
    if rad[0] != 0.0:
        raise ZemaxError(f"{path}: the radial angles must start at 0 (the specular direction), got {rad[0]:g}")
    v = tabulate(f, inc, az, rad)
    if list(channels) == ["R", "G", "B"]:
        v = np.einsum("xc,c...->x...", RGB_TO_XYZ, v)
        labels = ["TristimulusX", "TristimulusY", "TristimulusZ"]
        spectral = "XYZ"
    elif v.shape[0] == 1:
        labels, spectral = ["Monochrome"], "Monochrome"
    else:
        raise ZemaxError(f"{path}: Zemax output needs grey or RGB channels, got {list(channels)}")
    from reconstruction.core.metrics import directional_albedo

    tis = directional_albedo(f, np.radians(np.minimum(inc, 89.99)), 128, 256).T  # (C, I), accurate quadrature
    if spectral == "XYZ":
        tis = RGB_TO_XYZ @ tis
    fmt = lambda a: "\t".join(f"{x:g}" for x in a)  # noqa: E731
    out = [f"#{c}" for c in comments]
    out += ["Source  Measured", "Symmetry  PlaneSymmetrical", f"SpectralContent  {spectral}", "ScatterType  BRDF",
            "SampleRotation  1", "0", f"AngleOfIncidence  {inc.size}", fmt(inc), f"ScatterAzimuth  {az.size}",
            fmt(az), f"ScatterRadial  {rad.size}", fmt(rad), ""]
    for c, label in enumerate(labels):  # one or three sections
        out += [label, "DataBegin"]
        for k in range(inc.size):  # a block per incidence
            out.append(f"TIS {tis[c, k]:.6g}")
            rows = np.char.mod("%.6e", v[c, k])
            out.extend("\t".join(r) for r in rows)
        out.append("DataEnd")
    text = "\n".join(out) + "\n"
    with atomic_open(path, "w", encoding="utf-8") as fh:
        fh.write(text)
    return {"zemax": str(path), "zemax_bytes": len(text.encode("utf-8")), "symmetry": "PlaneSymmetrical",
            "spectral_content": spectral, "incidence_deg": inc.tolist(), "azimuth_deg": az.tolist(),
            "radial_deg": rad.tolist(), "tis": {lb: np.round(tis[c], 6).tolist() for c, lb in enumerate(labels)}}


def load_input(path: str | Path) -> tuple[SliceWithPoints, list[str], ZemaxBSDF]:
    """Read a Zemax file and turn it into the methods' input (:func:`to_slices`); returns (slice, notes, data)."""
    z = read(path)
    s, notes = to_slices(z)
    if len(s) < 3:
        raise ZemaxError(f"{path}: only {len(s)} in-plane samples (azimuths 0 and 180, |theta_o| <= 89 deg); "
                         f"a reconstruction needs at least 3")
    alb = file_albedo(z)
    tis_note = "; ".join(f"{x:g}: TIS line {t:.4g}, integral of the values {a:.4g}" for x, t, a in
                         zip(z.incidence_deg, z.tis.mean(axis=(0, 1)), alb.mean(axis=(0, 1)), strict=True))
    notes.append(f"{path}: per incidence (deg) {tis_note}")
    return s, notes, z



def load_inputs(paths: Sequence[str | Path], quantity: str | None = None, columns: str | None = None
                ) -> LoadedInput | None:
    """The gonio-reconstruct inputs as a :class:`~reconstruction.formats.inputs.LoadedInput` if they are a Zemax file,
    None if none of them is; :class:`ZemaxError` for a Zemax file among other inputs or with --quantity/--columns."""
    found = [p for p in paths if is_zemax(p)]
    if not found:
        return None
    check_whole_file_input(paths, found[0], "Zemax", quantity, columns, ZemaxError)
    s, notes, _ = load_input(found[0])
    return LoadedInput(s, [str(found[0])], ["brdf"], 0, notes)
