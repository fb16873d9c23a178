"""Any BRDF file we read as f(wi, wo) (reconstruction.formats.brdffile.load_brdf): RGL tensor files (ours and
hand-made spectral ones), Zemax grids, MERL tables, neural BRDFs, material files; an RGL file as the input of
gonio-reconstruct; clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reconstruction import cli
from reconstruction.core import merltable
from reconstruction.core.colour import spectra_to_rgb
from reconstruction.core.metrics import uniform_pairs
from reconstruction.core.models import Colour, Lambert, Material, Microfacet, Nbrdf
from reconstruction.formats import merl, rgl, zemax
from reconstruction.formats.brdffile import BRDFFileError, load_brdf, sample_brdf

MAT = Material("demo-like", [Lambert(colour=Colour(np.array([0.10, 0.20, 0.30]))),
                             Microfacet(colour=Colour(np.array([0.9, 0.9, 0.9])), alpha=0.15, f0=0.04)])


def random_pairs(n):
    """Direction pairs uniform in solid angle with both polar angles within 80 deg (fixed seed)."""
    return uniform_pairs(n, 80.0, seed=5)


def median_rel(a, b):
    return float(np.median(np.abs(a - b) / np.maximum(np.abs(b), 1e-12)))


@pytest.fixture(scope="module")
def rgl_file(tmp_path_factory):
    p = tmp_path_factory.mktemp("rgl") / "m.bsdf"
    rgl.write(p, MAT.eval)
    return p


def test_our_rgl_output_reads_back_as_the_brdf_within_one_percent(rgl_file):
    b = load_brdf(rgl_file)
    assert b.kind == "rgl" and b.channels == ["R", "G", "B"]
    wi, wo = random_pairs(3000)
    assert median_rel(b(wi, wo), MAT.eval(wi, wo)) < 0.01
    # any azimuth of wi: the file is isotropic, so rotating both directions about the normal changes nothing
    c, s = np.cos(1.1), np.sin(1.1)
    rot = np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])
    np.testing.assert_allclose(b(wi @ rot.T, wo @ rot.T), b(wi, wo), rtol=1e-6, atol=1e-9)
    assert np.all(b(wi * [1, 1, -1], wo) == 0)  # below the horizon


def spectral_fields(rgl_path, wavelengths):
    """A hand-made spectral database-style file from our RGB file: ``spectra`` (1, n_i, W, n, n) with each
    wavelength a fixed mix of the RGB values, ``wavelengths``, no ``rgb`` field and no ``luminance``."""
    f = dict(rgl.read_tensor_file(rgl_path))
    rgb = f.pop("rgb").astype(np.float64)  # (1, n_i, 3, n, n)
    f.pop("luminance")
    mix = np.linspace(0.0, 1.0, len(wavelengths))
    w = np.stack([1 - mix, 0.5 * np.ones_like(mix), mix], axis=1)  # (W, 3)
    f["spectra"] = np.einsum("wc,picxy->piwxy", w, rgb).astype(np.float32)
    f["wavelengths"] = np.asarray(wavelengths, dtype=np.float32)
    return f, w


def test_a_hand_made_spectral_file_reads_per_wavelength_and_as_rgb(tmp_path, rgl_file):
    wl = [400.0, 450.0, 500.0, 550.0, 600.0, 650.0, 700.0]
    fields, w = spectral_fields(rgl_file, wl)
    p = tmp_path / "spectral.bsdf"
    rgl.write_tensor_file(p, fields)
    spec = load_brdf(p, rgb=False)
    assert spec.channels == ["400nm", "450nm", "500nm", "550nm", "600nm", "650nm", "700nm"]
    wi, wo = random_pairs(500)
    rgb_of_ours = load_brdf(rgl_file)(wi, wo)
    np.testing.assert_allclose(spec(wi, wo), rgb_of_ours @ w.T, rtol=2e-5, atol=1e-7)
    as_rgb = load_brdf(p)  # default: linear sRGB
    assert as_rgb.channels == ["R", "G", "B"]
    np.testing.assert_allclose(as_rgb(wi, wo), spectra_to_rgb(spec(wi, wo), wl)[0], rtol=1e-9, atol=1e-12)


def test_an_anisotropic_or_incomplete_rgl_file_is_one_clear_error(tmp_path, rgl_file):
    f = dict(rgl.read_tensor_file(rgl_file))
    f["phi_i"] = np.zeros(4, dtype=np.float32)
    p = tmp_path / "aniso.bsdf"
    rgl.write_tensor_file(p, f)
    with pytest.raises(rgl.RGLError, match=r"aniso\.bsdf: anisotropic"):
        load_brdf(p)
    f = dict(rgl.read_tensor_file(rgl_file))
    del f["rgb"]
    rgl.write_tensor_file(p, f)
    with pytest.raises(rgl.RGLError, match=r"aniso\.bsdf: not a measured material: no field\(s\) rgb"):
        load_brdf(p)
    junk = tmp_path / "junk.dat"
    junk.write_bytes(b"hello")
    with pytest.raises(BRDFFileError, match=r"junk\.dat: unknown kind of file; expected an RGL"):
        load_brdf(junk)


def test_zemax_merl_nbrdf_and_material_files_load_as_brdfs(tmp_path):
    grey = Material("grey", [Lambert(colour=Colour(np.array([0.2]))),
                             Microfacet(colour=Colour(np.array([0.8])), alpha=0.3, f0=None)])
    z = tmp_path / "g.bsdf"
    zemax.write(z, grey.eval, ["value"])
    b = load_brdf(z)
    assert b.kind == "zemax" and b.channels == ["value"]
    wi, wo = random_pairs(2000)
    assert median_rel(b(wi, wo), grey.eval(wi, wo)) < 0.01  # the grid interpolated
    zi, zo = zemax.scatter_directions(30.0, np.array([0.0, 35.0, 90.0]), np.array([0.5, 6.0, 25.0]))
    np.testing.assert_allclose(b(zi, zo), grey.eval(zi, zo), rtol=1e-5)  # at grid nodes: the file's values

    t = tmp_path / "m.binary"
    merl.write(t, merltable.tabulate(MAT.eval))
    m = load_brdf(t)
    assert m.kind == "merl"
    np.testing.assert_allclose(m(wi, wo), merltable.lookup(merl.read(t), wi, wo, interpolate=True), rtol=1e-12)

    rng = np.random.default_rng(0)
    shapes = {"fc1": (6, 21), "b1": (21,), "fc2": (21, 21), "b2": (21,), "fc3": (21, 3), "b3": (3,)}
    for k, shp in shapes.items():
        np.save(tmp_path / f"net_{k}.npy", rng.normal(scale=0.3, size=shp))
    n = load_brdf(tmp_path / "net_fc1.npy")
    assert n.kind == "nbrdf"
    np.testing.assert_allclose(n(wi, wo), Nbrdf(path=str(tmp_path / "net")).eval(wi, wo, 3))
    np.testing.assert_allclose(load_brdf(tmp_path / "net")(wi, wo), n(wi, wo))

    toml = tmp_path / "mat.toml"
    toml.write_text('[material]\nname = "m"\n[[material.lobes]]\ntype = "lambert"\nalbedo = 0.5\n')
    mt = load_brdf(toml)
    np.testing.assert_allclose(mt(wi, wo), np.full((len(wi), 1), 0.5 / np.pi))


def test_an_rgl_file_is_an_input_of_gonio_reconstruct(tmp_path, rgl_file):
    """Sampled on a hemispherical grid: fit recovers the material's lobe from the file's values."""
    s = sample_brdf(load_brdf(rgl_file))
    assert len(s.points) > 5 * len(s) and np.ptp(s.points.wo[:, 1]) > 0.9  # out-of-plane points
    rep = tmp_path / "r.json"
    assert cli.main([str(rgl_file), "--method", "fit", "--out", str(tmp_path / "m.binary"), "--report", str(rep),
                     "--quiet"]) == 0
    r = json.loads(rep.read_text())
    lobes = {lb["type"]: lb for lb in r["details"]["material"]["lobes"]}
    assert lobes["ggx"]["alpha"] == pytest.approx(0.15, rel=0.03)
    np.testing.assert_allclose(lobes["lambert"]["albedo"], [0.1, 0.2, 0.3], rtol=0.05)
    assert any("RGL measured material" in n for n in r["inputs"]["notes"])


def test_a_bad_rgl_input_is_one_line_and_exit_2(tmp_path, capsys, rgl_file):
    f = dict(rgl.read_tensor_file(rgl_file))
    del f["vndf"]
    p = tmp_path / "bad.bsdf"
    rgl.write_tensor_file(p, f)
    assert cli.main([str(p), "--out", str(tmp_path / "m.binary"), "--quiet"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "bad.bsdf: not a measured material: no field(s) vndf" in err[0]


def test_a_whole_hemisphere_file_is_read_on_its_own(tmp_path, rgl_file):
    """An RGL or Zemax input holds every incidence and f_r: with another input, --quantity or --columns it is one
    clear error naming the file, in its format's own error class."""
    from reconstruction.formats import brdffile

    z = tmp_path / "z.bsdf"
    zemax.write(z, MAT.eval, ["R", "G", "B"], incidence_deg=[0.0, 30.0], azimuth_deg=[0.0, 90.0, 180.0],
                radial_deg=[0.0, 10.0, 30.0])
    other = tmp_path / "s.csv"
    for load, path, err, kind in ((brdffile.load_inputs, rgl_file, BRDFFileError, "RGL"),
                                  (zemax.load_inputs, z, zemax.ZemaxError, "Zemax")):
        with pytest.raises(err, match=rf"{path.name}: a {kind} file is read on its own .* got 2 inputs"):
            load([path, other])
        with pytest.raises(err, match=rf"a {kind} file holds f_r \(1/sr\); --quantity reflectance_factor"):
            load([path], "reflectance_factor")
        with pytest.raises(err, match=rf"--columns applies to generic CSV tables, not to a {kind} file"):
            load([path], None, "theta_i=a")
        assert load([path]) is not None
