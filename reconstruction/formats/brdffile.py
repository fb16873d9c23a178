"""Any BRDF file we read, as a function f(wi, wo) -> (N, C), and as samples for a reconstruction.

:func:`load_brdf` recognises a file by its content (then its name):

* an RGL ``.bsdf`` tensor file (the RGL material database's isotropic files, spectral or RGB, and our own
  ``--rgl`` output): evaluated as Mitsuba 3's ``measured`` plugin does (:class:`~reconstruction.formats.rgl.RGLTable`);
* a Zemax tabular BSDF text file: its grid interpolated (trilinear in incidence, azimuth and radial angle about
  the specular direction, the incidence clamped to the file's range; :func:`zemax_brdf`);
* a MERL table (``.binary``, or any file of the format's size): trilinear interpolation between bin centres
  (:func:`reconstruction.core.merltable.brdf_of`; the table itself is :attr:`LoadedBRDF.table`);
* a neural BRDF (the published layout of asztr/Neural-BRDF: ``NAME_fc1.npy`` ... ``NAME_b3.npy``, the prefix
  ``NAME``, or a folder holding one such set): :class:`~reconstruction.core.models.Nbrdf`;
* a material file (``.toml``, :meth:`~reconstruction.core.models.Material.from_toml`).

Directions are unit vectors (N, 3) in the local frame (z = normal), wi towards the light; values f_r in 1/sr, 0
below the horizon. Spectral files give linear sRGB with ``rgb=True`` (the default: CIE 1931 2 deg, D65,
:func:`reconstruction.core.colour.spectra_to_rgb`), their wavelengths as channels otherwise.

:func:`load_inputs` makes an RGL file an input of ``gonio-reconstruct``: the BRDF sampled as a hemispherical
instrument would (:data:`SAMPLE_INCIDENCES_DEG` x the Zemax default azimuths and radial angles), its in-plane rows
for every method and every point for the methods that use points anywhere.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.base import ReconstructionError
from reconstruction.core import merltable
from reconstruction.core.geometry import inplane_to_dirs
from reconstruction.core.samples import SliceWithPoints, directional_slice
from reconstruction.formats import merl, rgl, zemax
from reconstruction.formats.inputs import LoadedInput, check_whole_file_input

Array = NDArray[np.float64]

__all__ = ["BRDFFileError", "LoadedBRDF", "load_brdf", "zemax_brdf", "is_rgl", "load_inputs", "sample_brdf",
           "SAMPLE_INCIDENCES_DEG"]

#: incidences (deg) at which an RGL input is sampled (azimuths and radial angles: the Zemax default grid)
SAMPLE_INCIDENCES_DEG = np.arange(0.0, 81.0, 5.0)
#: in-plane outgoing angles (deg) of an RGL input's slices
SAMPLE_THETA_O_DEG = np.arange(-85.0, 85.5, 1.0)


class BRDFFileError(ReconstructionError):
    """A file is not a BRDF we read; the message names the file and what was expected."""


@dataclass
class LoadedBRDF:
    """A BRDF read from a file: call it (or ``eval``) with wi, wo (N, 3) for f_r (N, C) in 1/sr."""

    f: Callable[[Array, Array], ArrayLike]
    channels: list[str]
    source: str
    kind: str  # "rgl", "zemax", "merl", "nbrdf" or "material"
    name: str = ""  # the material's name: the material file's, the NBRDF set's prefix, else the file name
    table: Array | None = None  # a MERL file's table (3, 90, 90, 180)

    def __call__(self, wi: ArrayLike, wo: ArrayLike) -> Array:
        wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
        v = np.asarray(self.f(wi, wo), dtype=np.float64).reshape(wi.shape[0], -1)
        up = (wi[:, 2] > 0) & (wo[:, 2] > 0)
        return np.where(up[:, None], v, 0.0)

    eval = __call__


def is_rgl(path: str | Path) -> bool:
    """True for a regular file that starts with the tensor-file header."""
    p = Path(path)
    if not p.is_file():
        return False
    try:
        with open(p, "rb") as fh:
            return fh.read(len(rgl.TENSOR_MAGIC)) == rgl.TENSOR_MAGIC
    except OSError:
        return False


def _nbrdf_prefix(p: Path) -> Path | None:
    """The prefix of the neural-BRDF set that ``p`` names (the prefix, one of its files, or a folder holding one
    set), or None; :class:`BRDFFileError` for a folder of several sets."""
    from reconstruction.core.models import NBRDF_SUFFIXES

    for suffix in NBRDF_SUFFIXES:
        if p.name.endswith(f"_{suffix}.npy"):
            return p.with_name(p.name[: -len(f"_{suffix}.npy")])
    if p.is_dir():
        first = NBRDF_SUFFIXES[0]
        sets = sorted(q.name[: -len(f"_{first}.npy")] for q in p.glob(f"*_{first}.npy"))
        if len(sets) == 1:
            return p / sets[0]
        raise BRDFFileError(f"{p}: a folder with {len(sets)} neural-BRDF sets; {EXPECTED}")
    if Path(f"{p}_{NBRDF_SUFFIXES[0]}.npy").is_file():
        return p
    return None


#: what load_brdf reads, for its error messages
EXPECTED = ("expected an RGL .bsdf tensor file, a Zemax tabular BSDF, a MERL .binary table, a neural-BRDF npy set "
            "(PREFIX, PREFIX_fc1.npy or a folder holding one set) or a material .toml")


#: pairs per evaluation of an RGL file: bounds the temporaries of one RGLTable.eval call (it gathers a few cells per
#: pair: about 2 ms per 4096 pairs; it once built a density grid per pair, 0.33 s and a grid each per 4096 pairs)
RGL_BLOCK = 4096


def _in_blocks(f: Callable[[Array, Array], ArrayLike], n: int) -> Callable[[Array, Array], Array]:
    """``f`` evaluated ``n`` pairs at a time, results stacked (N, C)."""

    def g(wi: Array, wo: Array) -> Array:
        wi = np.asarray(wi, dtype=np.float64).reshape(-1, 3)
        wo = np.asarray(wo, dtype=np.float64).reshape(-1, 3)
        parts = [np.asarray(f(wi[k:k + n], wo[k:k + n]), dtype=np.float64).reshape(min(n, wi.shape[0] - k), -1)
                 for k in range(0, wi.shape[0], n)]
        return np.concatenate(parts) if parts else np.zeros((0, 1))

    return g


def _to_rgb(f: Callable[[Array, Array], ArrayLike], wavelengths_nm: Array) -> Callable[[Array, Array], Array]:
    from reconstruction.core.colour import spectral_to_rgb_matrix

    m = spectral_to_rgb_matrix(wavelengths_nm)
    return lambda wi, wo: np.asarray(f(wi, wo), dtype=np.float64) @ m


def zemax_brdf(z: zemax.ZemaxBSDF) -> tuple[Callable[[Array, Array], Array], list[str]]:
    """(f, channels) of a Zemax file's values: trilinear in (incidence, azimuth, radial) (degrees), azimuths closed
    over 360 deg (plane-symmetric files mirrored), the incidence clamped to the file's range; grey or linear sRGB."""
    az, v = z.full_azimuths()
    vals, channels = zemax.ZemaxBSDF(z.symmetry, z.spectral_content, z.scatter_type, z.sample_rotation_deg,
                                     z.incidence_deg, az, z.radial_deg, v, z.tis, z.channels).rgb_values()
    if az[-1] - az[0] < 360.0 - 1e-9:  # close the circle
        az = np.concatenate([az, [az[0] + 360.0]])
        vals = np.concatenate([vals, vals[:, :, :1]], axis=2)
    inc = z.incidence_deg
    if inc.size == 1:  # a single incidence: constant in theta_i
        inc = np.array([inc[0], inc[0] + 1e-6])
        vals = np.concatenate([vals, vals], axis=1)
    from scipy.interpolate import RegularGridInterpolator  # here: reading a slice file needs no scipy

    interp = RegularGridInterpolator((inc, az, z.radial_deg), np.moveaxis(vals, 0, -1), bounds_error=False,
                                     fill_value=None)
    lo, hi = float(inc[0]), float(inc[-1])

    def f(wi: Array, wo: Array) -> Array:
        phi = np.arctan2(wi[:, 1], wi[:, 0]) - np.pi  # rotate wi onto the -x side of the x-z plane
        c, s = np.cos(-phi), np.sin(-phi)
        rot = lambda w: np.stack([c * w[:, 0] - s * w[:, 1], s * w[:, 0] + c * w[:, 1], w[:, 2]], -1)  # noqa: E731
        t, a, r = zemax.zemax_angles(rot(wi), rot(wo))
        a = np.clip(a, az[0], az[-1])
        return np.maximum(interp(np.stack([np.clip(t, lo, hi), a, r], -1)), 0.0)

    return f, channels


def load_brdf(path: str | Path, *, rgb: bool = True) -> LoadedBRDF:
    """The BRDF of any file we read (module docstring) as a :class:`LoadedBRDF` f(wi, wo) -> (N, C) in 1/sr.

    ``rgb``: spectral files in linear sRGB (default) or in their own wavelengths. :class:`BRDFFileError` (one line
    naming the file) for anything else."""
    from reconstruction.core.models import MaterialError, Nbrdf

    p = Path(path)
    prefix = _nbrdf_prefix(p) if p.suffix in (".npy", "") or p.is_dir() else None
    if prefix is not None:
        try:
            lobe = Nbrdf(path=str(prefix))
            lobe._weights()
        except MaterialError as e:
            raise BRDFFileError(str(e) if str(p) in str(e) or str(prefix) in str(e) else f"{p}: {e}") from None
        return LoadedBRDF(lambda wi, wo: lobe.eval(wi, wo, 3), ["R", "G", "B"], str(p), "nbrdf", prefix.name)
    if not p.exists():
        raise BRDFFileError(f"{p}: no such file; {EXPECTED}")
    if not p.is_file():
        raise BRDFFileError(f"{p}: not a file; {EXPECTED}")
    try:
        return _load_file(p, rgb)
    except OSError as e:
        raise BRDFFileError(f"{p}: cannot read ({e.strerror or e})") from None


def _load_file(p: Path, rgb: bool) -> LoadedBRDF:
    from reconstruction.core.models import Material, MaterialError

    if is_rgl(p):
        t = rgl.RGLTable.read(p)
        ev = _in_blocks(t.eval, RGL_BLOCK)
        if t.wavelengths_nm is not None and rgb:
            return LoadedBRDF(_to_rgb(ev, t.wavelengths_nm), ["R", "G", "B"], str(p), "rgl", p.name)
        return LoadedBRDF(ev, list(t.channels), str(p), "rgl", p.name)
    if zemax.is_zemax(p):
        f, channels = zemax_brdf(zemax.read(p))
        return LoadedBRDF(f, channels, str(p), "zemax", p.name)
    if p.suffix.lower() == ".toml":
        try:
            mat = Material.from_toml(p)
        except MaterialError as e:
            raise BRDFFileError(str(e)) from None
        if mat.wavelengths_nm is not None and rgb:
            return LoadedBRDF(_to_rgb(mat.eval, np.asarray(mat.wavelengths_nm)), ["R", "G", "B"], str(p),
                              "material", mat.name)
        ch = (["value"] if mat.n_channels == 1 else ["R", "G", "B"] if mat.wavelengths_nm is None
              else [f"{w:g}nm" for w in mat.wavelengths_nm])
        return LoadedBRDF(mat.eval, ch, str(p), "material", mat.name)
    if p.suffix.lower() == ".binary" or p.stat().st_size == merl.FILE_SIZE:
        try:
            table = merl.read(p)
        except merltable.MerlError as e:
            raise BRDFFileError(str(e) if str(p) in str(e) else f"{p}: {e}") from None
        return LoadedBRDF(merltable.brdf_of(table, interpolate=True), ["R", "G", "B"], str(p), "merl", p.name, table)
    raise BRDFFileError(f"{p}: unknown kind of file; {EXPECTED}")


def sample_brdf(b: LoadedBRDF, incidence_deg: ArrayLike = SAMPLE_INCIDENCES_DEG,
                azimuth_deg: ArrayLike = zemax.DEFAULT_AZIMUTHS_DEG, radial_deg: ArrayLike = zemax.DEFAULT_RADIALS_DEG,
                theta_o_deg: ArrayLike = SAMPLE_THETA_O_DEG, max_theta_o_deg: float = 89.0) -> SliceWithPoints:
    """The BRDF ``b`` sampled as an instrument would: in-plane slices at ``incidence_deg`` x ``theta_o_deg`` for
    every method, carrying the points of a Zemax grid (incidence x azimuth x radial, degrees) above the horizon
    (within ``max_theta_o_deg``) for the methods that use points anywhere."""
    inc = np.asarray(incidence_deg, dtype=np.float64)
    ti, to = np.meshgrid(inc, np.asarray(theta_o_deg, dtype=np.float64), indexing="ij")
    ti, to = ti.ravel(), to.ravel()
    meta = {"quantity": "brdf", "source_kind": f"{b.kind} file sampled"}
    f_in = b(*inplane_to_dirs(np.radians(ti), np.radians(to)))
    s = SliceWithPoints(ti, to, f_in, list(b.channels), meta=meta, source=b.source)
    wi, wo = zemax.scatter_directions(inc[:, None, None], np.asarray(azimuth_deg)[None, :, None],
                                      np.asarray(radial_deg)[None, None, :])
    up = wo[..., 2] > np.cos(np.radians(max_theta_o_deg))
    s.points = directional_slice(wi[up], wo[up], b(wi[up], wo[up]), list(b.channels), meta=meta, source=b.source)
    return s


def load_inputs(paths: Sequence[str | Path], quantity: str | None = None, columns: str | None = None
                ) -> LoadedInput | None:
    """The gonio-reconstruct inputs as a :class:`~reconstruction.formats.inputs.LoadedInput` if they are an RGL
    tensor file (sampled by :func:`sample_brdf`, spectral files in their wavelengths), None if none of them is."""
    found = [p for p in paths if is_rgl(p)]
    if not found:
        return None
    check_whole_file_input(paths, found[0], "RGL", quantity, columns, BRDFFileError)
    try:
        b = load_brdf(found[0], rgb=False)
    except rgl.RGLError as e:
        raise BRDFFileError(str(e)) from None
    s = sample_brdf(b)
    assert s.points is not None
    note = (f"{found[0]}: RGL measured material ({len(b.channels)} channels), evaluated as Mitsuba 3's measured "
            f"plugin does and sampled at incidences {SAMPLE_INCIDENCES_DEG[0]:g}-{SAMPLE_INCIDENCES_DEG[-1]:g} deg "
            f"every {SAMPLE_INCIDENCES_DEG[1] - SAMPLE_INCIDENCES_DEG[0]:g}: {len(s)} in-plane samples for every "
            f"method, {len(s.points)} points above the horizon (Zemax default azimuths and radial angles) for the "
            f"methods that use points anywhere")
    return LoadedInput(s, [str(found[0])], ["brdf"], 0, [note])
