"""gonio-compare: two BRDFs judged as the field judges them (synthetic materials and tables only)."""

from __future__ import annotations

import json

import numpy as np
import pytest

from reconstruction.core import merltable
from reconstruction.core.metrics import cosl2, log_error, uniform_pairs
from reconstruction.core.models import Material
from reconstruction.formats import merl
from reconstruction.report import compare as cmp

MATERIAL = {"name": "plastic", "lobes": [{"type": "lambert", "albedo": [0.1, 0.2, 0.4]},
                                         {"type": "ggx", "alpha": 0.2, "specular": 0.8, "f0": 0.04}]}
TOML = """[material]
name = "plastic"
[[material.lobes]]
type = "lambert"
albedo = [0.1, 0.2, 0.4]
[[material.lobes]]
type = "ggx"
alpha = 0.2
specular = 0.8
f0 = 0.04
"""


@pytest.fixture(scope="module")
def table() -> np.ndarray:
    return merltable.tabulate(Material.from_dict(MATERIAL).eval)


@pytest.fixture(scope="module")
def files(tmp_path_factory, table):
    d = tmp_path_factory.mktemp("cmp")
    merl.write(d / "a.binary", table)
    merl.write(d / "double.binary", 2.0 * table)
    (d / "plastic.toml").write_text(TOML, encoding="utf-8")
    return d


def test_uniform_pairs_are_uniform_in_solid_angle_within_the_cap():
    wi, wo = uniform_pairs(40_000, 80.0, seed=1)
    for d in (wi, wo):
        assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
        assert d[:, 2].min() >= np.cos(np.radians(80.0)) - 1e-12
        # uniform in solid angle: cos theta uniform over [cos 80, 1], azimuth uniform
        assert abs(np.mean(d[:, 2]) - 0.5 * (1 + np.cos(np.radians(80.0)))) < 0.01
        assert abs(np.mean(d[:, 0])) < 0.01 and abs(np.mean(d[:, 1])) < 0.01


def test_cosl2_and_log_error_by_hand():
    wi, wo = uniform_pairs(1000, 80.0)
    g = np.full((1000, 3), 0.2)
    assert cosl2(g, g, wi, wo) == 0.0 and log_error(g, g, wi) == 0.0
    assert cosl2(1.5 * g, g, wi, wo) == pytest.approx(0.5)  # a uniform 50 % excess
    c = wi[:, 2:3]
    want = np.mean(np.abs(np.log((0.4 * c + 1e-3) / (0.2 * c + 1e-3))))
    assert log_error(2.0 * g, g, wi) == pytest.approx(want)


def test_a_table_compared_with_itself_is_zero_and_infinite_psnr(files, tmp_path, capsys):
    out = tmp_path / "same.json"
    png = tmp_path / "same.png"
    assert cmp.main([str(files / "a.binary"), str(files / "a.binary"), "--size", "16", "--json", str(out),
                     "--png", str(png)]) == 0
    res = json.loads(out.read_text())
    assert res["cosl2"] == 0.0 and res["log_error"] == 0.0 and res["rmse80"] == 0.0
    for light in ("key", "rim"):
        assert res["image"][light]["relative_rmse"] == 0.0
        assert res["image"][light]["psnr_db"] is None  # infinite: null in strict JSON
    assert res["a"]["kind"] == res["b"]["kind"] == "merl"
    assert png.stat().st_size > 1000
    assert "inf dB (identical)" in capsys.readouterr().out


def test_a_table_twice_too_bright(files, table):
    res = cmp.compare(cmp.load_brdf(files / "double.binary"), cmp.load_brdf(files / "a.binary"), size=16)
    # f doubled everywhere: every relative error of f and of the linear images is exactly 100 %
    assert res["cosl2"] == pytest.approx(1.0, rel=1e-9)
    assert res["rmse80"] == pytest.approx(1.0, rel=1e-9)
    for light in ("key", "rim"):
        assert res["image"][light]["relative_rmse"] == pytest.approx(1.0, rel=1e-9)
        assert res["image"][light]["relative_rmse_but_brightest_pixel"] == pytest.approx(1.0, rel=1e-9)
        assert 5.0 < res["image"][light]["psnr_db"] < 40.0
    assert 0.0 < res["rmse80_grazing_share"] < 1.0
    assert 0.2 < res["log_error"] < np.log(2.0)


def test_a_material_against_its_own_table_is_close(files, table):
    a = cmp.load_brdf(files / "a.binary")
    b = cmp.load_brdf(files / "plastic.toml")
    assert b.kind == "material" and b.table is None
    res = cmp.compare(a, b, size=16)
    assert 0.0 < res["cosl2"] < 0.05 and 0.0 < res["log_error"] < 0.05
    assert res["image"]["psnr_db"] > 35.0
    assert res["rmse80"] < 0.05  # the material tabulated at the bin centres: the same table


def test_a_neural_brdf_set_by_prefix_file_or_folder(tmp_path):
    rng = np.random.default_rng(0)
    shapes = {"fc1": (6, 21), "b1": (21,), "fc2": (21, 21), "b2": (21,), "fc3": (21, 3), "b3": (3,)}
    for k, s in shapes.items():
        np.save(tmp_path / f"m_{k}.npy", 0.3 * rng.standard_normal(s))
    ref = cmp.load_brdf(tmp_path / "m")
    wi, wo = uniform_pairs(50)
    for p in (tmp_path / "m_fc2.npy", tmp_path):
        b = cmp.load_brdf(p)
        assert b.kind == "nbrdf" and b.name == "m"
        np.testing.assert_array_equal(b.values(wi, wo), ref.values(wi, wo))
    np.save(tmp_path / "n_fc1.npy", np.zeros((6, 21)))  # a second (incomplete) set: the folder is ambiguous
    with pytest.raises(cmp.CompareError, match="2 neural-BRDF sets"):
        cmp.load_brdf(tmp_path)


@pytest.mark.parametrize("name, content, expect", [
    ("missing.binary", None, "no such file"),
    ("short.binary", b"\x5a\x00\x00\x00", "too short"),
    ("bad.toml", b"[other]\nx = 1\n", "no [material] table"),
    ("notes.txt", b"hello", "unknown kind of file; expected an RGL .bsdf tensor file"),
    ("junk.bsdf", b"not a tensor file", "junk.bsdf"),
    ("x_fc1.npy", b"not numpy", "x_"),
])
def test_bad_input_is_one_line_and_exit_2(files, tmp_path, capsys, name, content, expect):
    p = tmp_path / name
    if content is not None:
        p.write_bytes(content)
    assert cmp.main([str(p), str(files / "a.binary"), "--size", "16"]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and err.startswith("gonio-compare: error: ") and str(p) in err and expect in err


def test_a_bad_size_is_a_usage_error(files, capsys):
    with pytest.raises(SystemExit) as e:
        cmp.main([str(files / "a.binary"), str(files / "a.binary"), "--size", "2"])
    assert e.value.code == 2 and "--size" in capsys.readouterr().err


def test_the_linear_error_without_the_brightest_pixel():
    from reconstruction.core.metrics import image_relative_rmse

    rng = np.random.default_rng(3)
    truth = rng.uniform(0.5, 1.0, (8, 8, 3))
    truth[3, 4] = 400.0  # a highlight: one pixel far above the rest
    img = truth.copy()
    img[3, 4] = 100.0  # the highlight a quarter as bright, every other pixel exact
    want = np.sqrt(3 * 300.0**2 / np.sum(truth**2))
    assert image_relative_rmse(img, truth) == pytest.approx(want, rel=1e-12)
    assert image_relative_rmse(img, truth, leave_out_brightest=1) == 0.0
    img[4, 3] *= 1.1  # and one dim pixel 10 % off: that one counts
    rest = np.delete(truth.reshape(-1, 3), 3 * 8 + 4, axis=0)
    want = np.sqrt(np.sum((0.1 * truth[4, 3]) ** 2) / np.sum(rest**2))
    assert image_relative_rmse(img, truth, leave_out_brightest=1) == pytest.approx(want, rel=1e-12)
    # compare's figures carry it per lighting and as the mean of the two (both pixels lie on the sphere's disk)
    mask = cmp.view_angle_mask(8, 1.0, cmp.IMAGE_MAX_VIEW_DEG)
    assert mask[3, 4] and mask[4, 3]
    want = np.sqrt(np.sum((0.1 * truth[4, 3]) ** 2) / np.sum(np.delete(truth[mask], int(np.flatnonzero(
        np.flatnonzero(mask.ravel()) == 3 * 8 + 4)[0]), axis=0) ** 2))
    res = cmp.image_metrics({"key": img, "rim": truth}, {"key": truth, "rim": truth}, 8)
    assert res["key"]["relative_rmse_but_brightest_pixel"] == pytest.approx(want, rel=1e-12)
    assert res["rim"]["relative_rmse_but_brightest_pixel"] == 0.0
    assert res["relative_rmse_but_brightest_pixel"] == pytest.approx(want / 2, rel=1e-12)


def test_a_grey_photodiode_table_against_a_colour_truth_is_read_in_the_band(files, table, tmp_path, capsys):
    """Issue 41: a photodiode's grey table against its RGB truth was judged channel by channel (18.5 dB, 45 %) with
    no word. Now the truth is read in the photodiode's band and the output says so; --no-band says it compares
    grey with colour."""
    from reconstruction.schema.optics import rgb_band_weights

    w = rgb_band_weights()
    np.testing.assert_allclose(w, [0.452, 0.337, 0.211], atol=2e-3)  # silicon x halogen-3000K (docs/instrument.md)
    grey = np.broadcast_to(np.tensordot(w, table, axes=1)[None], table.shape).copy()  # what the bench reads
    merl.write(tmp_path / "grey.binary", grey)
    out = tmp_path / "banded.json"
    assert cmp.main([str(tmp_path / "grey.binary"), str(files / "a.binary"), "--size", "16", "--json",
                     str(out)]) == 0
    printed = capsys.readouterr().out
    assert "A is grey (one channel, as a photodiode measures) and B colour: B read in the photodiode band " \
           "silicon x halogen-3000K" in printed
    res = json.loads(out.read_text())
    assert res["band"]["applied"] and res["band"]["band"] == "silicon x halogen-3000K"
    assert res["rmse80"] < 1e-3 and res["cosl2"] < 1e-3  # the same reading, once in the same band
    g, c = cmp.load_brdf(tmp_path / "grey.binary"), cmp.load_brdf(files / "a.binary")
    _, _, note = cmp.band_matched(g, c, None)  # --no-band
    assert not note["applied"] and "compared as they are, grey against each colour channel" in note["note"]
    assert cmp.band_matched(c, c, ("silicon", "halogen-3000K"))[2] is None  # colour against colour: nothing to say
    assert cmp.band_matched(g, g, ("silicon", "halogen-3000K"))[2] is None
    assert cmp.main([str(tmp_path / "grey.binary"), str(files / "a.binary"), "--band", "silicon"]) == 2
    assert "--band: expected RESPONSIVITY,SOURCE" in capsys.readouterr().err
