"""Spectral -> linear sRGB through colour-science: white stays white, agrees with colour's own path, linear."""

import warnings

import numpy as np
import pytest

from reconstruction.base import ReconstructionError
from reconstruction.core.colour import resampling_interval, spectra_to_rgb, spectral_to_rgb_matrix, to_working_channels
from reconstruction.core.slicedata import Slice


@pytest.mark.parametrize("illuminant", ["D65", "A", "D50"])
@pytest.mark.parametrize("grid", [np.arange(400.0, 701.0, 10.0), np.arange(380.5, 781.0, 3.3),
                                  np.linspace(350, 900, 600)], ids=["10nm", "3.3nm", "0.9nm-wide"])
def test_perfect_reflector_is_white_under_any_illuminant(illuminant, grid):
    rgb, _ = spectra_to_rgb(np.ones((1, grid.size)), grid, illuminant)
    np.testing.assert_allclose(rgb[0], [1.0, 1.0, 1.0], atol=5e-4)


def test_matches_colour_science_per_sample_path():
    import colour

    wl = np.arange(400.0, 701.0, 10.0)
    rng = np.random.default_rng(3)
    spectra = rng.uniform(0, 1, (4, wl.size))
    rgb, _ = spectra_to_rgb(spectra, wl, "D65")
    cmfs = colour.MSDS_CMFS["CIE 1931 2 Degree Standard Observer"]
    ill = colour.SDS_ILLUMINANTS["D65"]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        white = colour.sd_to_XYZ(colour.SpectralDistribution(np.ones(wl.size), wl), cmfs, ill)
        for k in range(4):  # the slow, obvious way: one spectrum at a time through colour
            xyz = colour.sd_to_XYZ(colour.SpectralDistribution(spectra[k], wl), cmfs, ill) / white[1]
            ref = colour.XYZ_to_RGB(xyz, "sRGB", illuminant=colour.XYZ_to_xy(white / white[1]),
                                    apply_cctf_encoding=False)
            np.testing.assert_allclose(rgb[k], ref, rtol=1e-9, atol=1e-12)


def test_red_spectrum_is_red_and_scaling_is_linear():
    wl = np.arange(400.0, 701.0, 5.0)
    red = (wl >= 610).astype(float)
    rgb, _ = spectra_to_rgb(np.stack([red, 0.25 * red]), wl)
    assert rgb[0, 0] > 3 * max(rgb[0, 1], rgb[0, 2], 0.01)
    np.testing.assert_allclose(rgb[1], 0.25 * rgb[0], rtol=1e-12)


def test_resampling_interval():
    assert resampling_interval(np.arange(400, 701, 10.0)) == 10
    assert resampling_interval(np.arange(400, 701, 25.0)) == 20
    assert resampling_interval(np.arange(400, 701, 3.3)) == 1
    assert resampling_interval(np.arange(400, 701, 0.4)) == 1
    assert resampling_interval(np.arange(400, 701, 7.0)) == 5


def test_working_channels_spectral_to_rgb_and_grey_unchanged():
    wl = np.arange(400.0, 701.0, 20.0)
    names = [f"{int(w)}nm" for w in wl]
    v = np.full((3, wl.size), 0.3)
    s = Slice([30, 30, 30], [-10, 0, 10], v, names, np.full_like(v, 0.01))
    out, info = to_working_channels(s)
    assert out.channels == ["R", "G", "B"]
    np.testing.assert_allclose(out.values, 0.3, atol=2e-4)
    assert np.all(out.std > 0) and np.all(out.std < 0.01)  # averaging over wavelengths reduces the noise
    assert "D65" in info["conversion"]
    g = Slice([30, 30, 30], [-10, 0, 10], [[1.0], [2.0], [3.0]], ["value"])
    same, info = to_working_channels(g)
    assert same is g and info["conversion"] == "none"


def test_bad_spectral_input():
    with pytest.raises(ReconstructionError, match="unknown illuminant 'D99'"):
        spectral_to_rgb_matrix(np.arange(400.0, 701.0, 10.0), "D99")
    with pytest.raises(ReconstructionError, match="outside the observer"):
        spectral_to_rgb_matrix(np.array([900.0, 950.0]))
    with pytest.raises(ReconstructionError, match="increasing"):
        spectral_to_rgb_matrix(np.array([500.0, 450.0]))
