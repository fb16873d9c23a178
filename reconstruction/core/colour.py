"""Spectral samples -> linear sRGB, through colour-science (imported lazily: it takes ~0.6 s).

Each sample's spectrum becomes XYZ with the CIE 1931 2 degree observer under an illuminant (D65 by default,
ASTM E308 weighting), after linear resampling onto a 1, 5, 10 or 20 nm grid (the largest interval not coarser
than the data's median spacing, 1 nm at least) inside the measured range. XYZ is normalised so that a perfect
reflector (value 1 at every wavelength) has Y = 1, then converted to linear sRGB with a CAT02 chromatic
adaptation from the illuminant's white to sRGB's D65 white, so the perfect reflector gives RGB (1, 1, 1)
under any illuminant. No transfer function (gamma) is applied.

All of this is linear in the spectrum, so it is computed once as a matrix M (W, 3) with rgb = values @ M;
standard deviations propagate as sqrt(std^2 @ M^2) (independent wavelengths assumed).
"""

from __future__ import annotations

import warnings
from functools import lru_cache

import numpy as np
from numpy.typing import ArrayLike, NDArray

from reconstruction.base import ReconstructionError
from reconstruction.core.slicedata import Slice

Array = NDArray[np.float64]

__all__ = ["DEFAULT_ILLUMINANT", "OBSERVER", "ASTM_INTERVALS", "resampling_interval", "spectral_to_rgb_matrix",
           "spectra_to_rgb", "to_working_channels", "illuminant_names", "srgb_reflectance_basis"]

DEFAULT_ILLUMINANT = "D65"
OBSERVER = "CIE 1931 2 Degree Standard Observer"
ASTM_INTERVALS = (1, 5, 10, 20)


def illuminant_names() -> list[str]:
    """Names accepted for ``illuminant`` (colour-science's ``SDS_ILLUMINANTS``)."""
    import colour

    return sorted(colour.SDS_ILLUMINANTS)


def resampling_interval(wavelengths_nm: ArrayLike) -> int:
    """The ASTM E308 interval (1, 5, 10 or 20 nm) for a grid: the largest not coarser than its median spacing."""
    wl = np.asarray(wavelengths_nm, dtype=np.float64)
    if wl.size < 2:
        return 1
    step = float(np.median(np.diff(wl)))
    ok = [i for i in ASTM_INTERVALS if i <= step + 1e-9]
    return ok[-1] if ok else 1


def _interp_matrix(src: Array, dst: Array) -> Array:
    """(len(src), len(dst)) matrix R with values_dst = values_src @ R (linear interpolation, src increasing)."""
    k = np.clip(np.searchsorted(src, dst, side="right") - 1, 0, src.size - 2)
    t = np.clip((dst - src[k]) / (src[k + 1] - src[k]), 0.0, 1.0)
    r = np.zeros((src.size, dst.size))
    cols = np.arange(dst.size)
    r[k, cols] += 1.0 - t
    r[k + 1, cols] += t
    return r


@lru_cache(maxsize=16)
def _matrix_cached(wavelengths: tuple[float, ...], illuminant: str) -> Array:
    import colour

    wl = np.asarray(wavelengths)
    if illuminant not in colour.SDS_ILLUMINANTS:
        near = [n for n in colour.SDS_ILLUMINANTS if n.upper().startswith(illuminant[:1].upper())][:8]
        raise ReconstructionError(f"--illuminant: unknown illuminant {illuminant!r}; for example "
                                  f"{', '.join(near or ['D65', 'D50', 'A'])}")
    cmfs = colour.MSDS_CMFS[OBSERVER]
    lo, hi = float(cmfs.shape.start), float(cmfs.shape.end)
    if wl[-1] < lo or wl[0] > hi:
        raise ReconstructionError(f"spectral channels {wl[0]:g}-{wl[-1]:g} nm lie outside the observer's "
                                  f"{lo:g}-{hi:g} nm")
    step = resampling_interval(wl)
    start = np.ceil(max(wl[0], lo) / step) * step
    end = np.floor(min(wl[-1], hi) / step) * step
    if end - start < step:
        raise ReconstructionError(f"spectral channels {wl[0]:g}-{wl[-1]:g} nm: too narrow a range for colour")
    grid = np.arange(start, end + step / 2, step)
    resample = _interp_matrix(wl, grid)  # (W, G)
    basis = colour.MultiSpectralDistributions(np.eye(grid.size), grid,
                                              labels=[f"b{k}" for k in range(grid.size)])
    ill = colour.SDS_ILLUMINANTS[illuminant]
    with warnings.catch_warnings():  # colour warns about aligning/trimming shapes, which is what we ask for
        warnings.simplefilter("ignore")
        xyz = np.asarray(colour.msds_to_XYZ(basis, cmfs, ill), dtype=np.float64).reshape(grid.size, 3)
        white = np.ones(grid.size) @ xyz  # the perfect reflector's XYZ (Y = 100)
        xyz = xyz / white[1]  # Y of the perfect reflector = 1
        white_xy = colour.XYZ_to_xy(white / white[1])
        to_rgb = np.asarray(colour.XYZ_to_RGB(np.eye(3), "sRGB", illuminant=white_xy,
                                              chromatic_adaptation_transform="CAT02", apply_cctf_encoding=False))
    m = resample @ xyz @ to_rgb  # (W, 3): rgb = values @ m
    m.setflags(write=False)
    return m


def spectral_to_rgb_matrix(wavelengths_nm: ArrayLike, illuminant: str = DEFAULT_ILLUMINANT) -> Array:
    """Matrix M (W, 3) with linear sRGB = spectrum (..., W) @ M, for channels at ``wavelengths_nm`` (increasing).

    ``illuminant`` names a colour-science illuminant (``D65``, ``D50``, ``A``, ...). Cached per grid.
    """
    wl = np.asarray(wavelengths_nm, dtype=np.float64).reshape(-1)
    if wl.size < 2 or np.any(np.diff(wl) <= 0):
        raise ReconstructionError(f"spectral channels need at least two increasing wavelengths, got {wl.tolist()}")
    return _matrix_cached(tuple(float(x) for x in wl), illuminant)


def spectra_to_rgb(values: ArrayLike, wavelengths_nm: ArrayLike, illuminant: str = DEFAULT_ILLUMINANT,
                   std: ArrayLike | None = None) -> tuple[Array, Array | None]:
    """(rgb (N, 3), rgb std (N, 3) or None) of spectra ``values`` (N, W) on ``wavelengths_nm`` (nm)."""
    m = spectral_to_rgb_matrix(wavelengths_nm, illuminant)
    v = np.asarray(values, dtype=np.float64)
    rgb = v @ m
    if std is None:
        return rgb, None
    return rgb, np.sqrt(np.square(np.asarray(std, dtype=np.float64)) @ np.square(m))


def to_working_channels(s: Slice, illuminant: str = DEFAULT_ILLUMINANT) -> tuple[Slice, dict[str, object]]:
    """The slice in the channels the methods work in: grey and RGB unchanged, spectral -> linear sRGB.

    Returns (slice, info) where info says what was done (for the report).
    """
    kind = s.kind
    if kind != "spectral":
        return s, {"input_channels": kind, "working_channels": list(s.channels), "conversion": "none"}
    wl = s.wavelengths_nm
    assert wl is not None and s.std is not None
    rgb, std = spectra_to_rgb(s.values, wl, illuminant, s.std)
    out = Slice(s.theta_i_deg, s.theta_o_deg, rgb, ["R", "G", "B"], std, s.repeats, s.unix_time_s,
                meta=dict(s.meta), source=s.source)
    info = {"input_channels": "spectral", "wavelengths_nm": [float(wl[0]), float(wl[-1])],
            "n_wavelengths": int(wl.size), "working_channels": ["R", "G", "B"],
            "conversion": f"{OBSERVER}, illuminant {illuminant}, ASTM E308, resampled to "
                          f"{resampling_interval(wl)} nm, CAT02 to the sRGB white, linear sRGB"}
    return out, info


def srgb_reflectance_basis(grid_nm: ArrayLike) -> Array:
    """(len(grid_nm), 3): the reflectance spectra of linear sRGB R, G, B (Mallett and Yuksel 2019, colour-science's
    MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019, linearly interpolated onto ``grid_nm`` (nm), clamped at its ends): an
    albedo (r, g, b) is the spectrum r B_R + g B_G + b B_B, and (1, 1, 1) a flat reflectance of 1. The simulator
    turns RGB materials into spectra with the same basis (read through the same disk cache)."""
    from importlib.metadata import version

    from reconstruction.cache import cached_arrays

    def build() -> tuple[Array, Array]:
        from colour.recovery import MSDS_BASIS_FUNCTIONS_sRGB_MALLETT2019 as basis

        return np.asarray(basis.wavelengths, dtype=float), np.asarray(basis.values, dtype=float)

    wl, values = cached_arrays("srgb-basis-mallett2019", f"colour-science {version('colour-science')}", build)
    grid = np.asarray(grid_nm, dtype=float)
    return np.stack([np.interp(grid, wl, values[:, k]) for k in range(3)], axis=1)
