"""Renderer-ready exports: the Mitsuba 3 fragment (loaded by Mitsuba 3 and compared with our model), the
parameters JSON, the Mitsuba preview, and the format flags of gonio-reconstruct."""

from __future__ import annotations

import json
import sys

import numpy as np
import OpenEXR
import pytest

from reconstruction import cli, pipeline
from reconstruction.core.models import Colour, Lambert, Material, Microfacet
from reconstruction.formats import exports, zemax
from reconstruction.formats.slicefile import write_slice
from reconstruction.methods.fit import reconstruct_fit
from reconstruction.methods.microfacet import MicrofacetReconstruction
from reconstruction.synthetic import synthetic_slice


@pytest.fixture(scope="module")
def mi():
    import mitsuba

    mitsuba.set_variant("scalar_rgb")
    return mitsuba


def hemisphere(rng, n):
    z = rng.uniform(0.02, 1.0, n)
    p = rng.uniform(0.0, 2 * np.pi, n)
    s = np.sqrt(1.0 - z * z)
    return np.stack([s * np.cos(p), s * np.sin(p), z], axis=-1)


def compare(mi, path, rec, n=1000, seed=0):
    """Relative errors (N, 3) of Mitsuba's eval / cos theta_o of the XML at ``path`` against ``rec``."""
    bsdf = mi.load_file(str(path))
    ctx = mi.BSDFContext()
    rng = np.random.default_rng(seed)
    wi, wo = hemisphere(rng, n), hemisphere(rng, n)
    ref = np.asarray(rec.eval(wi, wo), dtype=np.float64).reshape(n, -1)
    ref = np.repeat(ref, 3, axis=1) if ref.shape[1] == 1 else ref
    got = np.zeros((n, 3))
    for k in range(n):  # scalar variant
        si = mi.SurfaceInteraction3f()
        si.wi = mi.Vector3f(*wi[k])
        got[k] = np.array(bsdf.eval(ctx, si, mi.Vector3f(*wo[k]))) / wo[k, 2]
    return np.abs(got - ref) / np.maximum(ref, 1e-6 * ref.max())


def fitted(mat, lobes, incidences=(20.0, 40.0, 60.0)):
    return reconstruct_fit(synthetic_slice(mat, incidences), lobes=lobes)


@pytest.mark.parametrize("dist", ["ggx", "beckmann"])
def test_a_fit_without_fresnel_maps_to_diffuse_plus_roughconductor_exactly(mi, tmp_path, dist):
    mat = Material("m", [Lambert(colour=Colour(np.array([0.05, 0.1, 0.4]))),
                         Microfacet(colour=Colour(np.array([0.5, 0.6, 0.7])), alpha=0.12, f0=None,
                                    distribution=dist)])
    rec = fitted(mat, ["lambert", dist])
    xml, info = exports.mitsuba_fragment(rec, "blue", None)
    assert info["maps"] and info["plugins"] == ["blendbsdf", "diffuse", "roughconductor"]
    assert '<string name="material" value="none"/>' in xml and f'value="{dist}"' in xml
    path = tmp_path / "blue.xml"
    path.write_text(xml)
    rel = compare(mi, path, rec)
    assert np.max(rel) < 2e-4  # the same function, to float32 precision


def test_the_microfacet_mixture_maps_term_by_term_with_its_exact_fresnel(mi, tmp_path):
    for kind, eta, kappa in (("dielectric", 1.6, 0.0), ("conductor", 0.4, 3.2), ("none", 1.0, 0.0)):
        rec = MicrofacetReconstruction(np.array([0.05, 0.2, 0.6]), np.array([0.5, 0.3, 0.2]), kind, eta, kappa,
                                       np.array([0.2, 0.25, 0.3]), np.array([0.7, 0.65, 0.6]), ["R", "G", "B"])
        xml, info = exports.mitsuba_fragment(rec, "mix", None)
        assert info["maps"] and info["leaves"] == 4
        path = tmp_path / f"{kind}.xml"
        path.write_text(xml)
        assert np.max(compare(mi, path, rec, 600)) < 2e-4, kind


def test_amplitudes_above_one_use_unbounded_colours_and_still_add_exactly(mi, tmp_path):
    rec = MicrofacetReconstruction(np.array([0.3]), np.array([1.0]), "dielectric", 1.5, 0.0, np.array([0.9]),
                                   np.array([1.0]), ["value"])
    xml, info = exports.mitsuba_fragment(rec, "bright", None)
    assert info["unbounded_colours"] and 'name="unbounded" value="true"' in xml
    path = tmp_path / "bright.xml"
    path.write_text(xml)
    assert np.max(compare(mi, path, rec, 400)) < 2e-4


def test_a_schlick_lobe_with_grey_specular_maps_to_principled_exactly(mi, tmp_path):
    """The demo material: lambert + GGX with Schlick's Fresnel (f0 0.04) and a grey specular 0.9."""
    mat = Material.from_toml("configs/simulated.toml")
    rec, _ = pipeline.reconstruct(synthetic_slice(mat, (20.0, 40.0, 60.0)), "fit")
    assert rec.result.name == "lambert+ggx(F)"
    xml, info = exports.mitsuba_fragment(rec, "demo", None)
    assert info["maps"] and info["plugins"] == ["blendbsdf", "diffuse", "principled"]
    assert '<float name="metallic" value="1"/>' in xml and '<float name="weight" value="0.9' in xml
    path = tmp_path / "demo.xml"
    path.write_text(xml)
    assert np.max(compare(mi, path, rec)) < 2e-4


def test_a_coloured_schlick_lobe_falls_back_to_the_measured_rgl_file(mi, tmp_path):
    mat = Material("coloured", [Lambert(colour=Colour(np.array([0.1, 0.1, 0.1]))),
                                Microfacet(colour=Colour(np.array([0.9, 0.6, 0.3])), alpha=0.15, f0=0.04)])
    s = tmp_path / "slice.csv"
    write_slice(s, synthetic_slice(mat, (20.0, 40.0, 60.0)))
    xml_path = tmp_path / "coloured.xml"
    assert cli.main([str(s), "--method", "fit", "--export-mitsuba", str(xml_path), "--export-json",
                     str(tmp_path / "p.json"), "--zemax", str(tmp_path / "coloured.bsdf"), "--quiet"]) == 0
    xml = xml_path.read_text()
    # the RGL file is written beside the XML (relative path), not over the Zemax file of the same stem
    assert '<bsdf type="measured"' in xml and 'value="coloured-rgl.bsdf"' in xml
    assert (tmp_path / "coloured-rgl.bsdf").read_bytes()[:12] == b"tensor_file\x00"
    assert zemax.is_zemax(tmp_path / "coloured.bsdf")
    rec, _ = pipeline.reconstruct(synthetic_slice(mat, (20.0, 40.0, 60.0)), "fit")
    rel = compare(mi, xml_path, rec)
    assert np.median(rel) < 0.05
    p = json.loads((tmp_path / "p.json").read_text())
    assert p["mitsuba"]["maps"] is False and "grey specular" in p["mitsuba"]["reason"]


def test_parameters_json_follows_the_schema():
    mat = Material.from_toml("configs/simulated.toml")
    s = synthetic_slice(mat, (20.0, 40.0, 60.0))
    rec, _ = pipeline.reconstruct(s, "fit")
    p = exports.parameters(rec)
    schema = json.loads(open("docs/parameters.schema.json").read())
    assert p["schema"] == exports.SCHEMA == schema["properties"]["schema"]["const"]
    assert set(schema["required"]) <= set(p)
    lobes = {lb["type"]: lb for lb in p["lobes"]}
    assert lobes["lambert"]["albedo"] == pytest.approx([0.05, 0.1, 0.4], rel=1e-4)
    assert lobes["ggx"]["alpha"] == pytest.approx(0.15, rel=1e-4)
    assert lobes["ggx"]["fresnel"]["kind"] == "schlick" and lobes["ggx"]["fresnel"]["f0"] == pytest.approx(0.04,
                                                                                                            rel=1e-3)
    assert p["analytic"] and "uncertainties" in p and p["channels"] == ["R", "G", "B"]
    json.dumps(p, allow_nan=False)
    bivariate, _ = pipeline.reconstruct(s, "bivariate")
    q = exports.parameters(bivariate)
    assert q["analytic"] is False and q["lobes"] == [] and q["mitsuba"]["plugins"] == ["measured"]
    micro, _ = pipeline.reconstruct(s, "microfacet")
    m = exports.parameters(micro)
    assert m["lobes"][1]["type"] == "ggx_mixture" and sum(t["weight"] for t in m["lobes"][1]["terms"]) == \
        pytest.approx(1.0)


@pytest.mark.slow
def test_preview_rendered_by_mitsuba_with_the_written_file(mi, tmp_path):
    mat = Material.from_toml("configs/simulated.toml")
    s = tmp_path / "slice.csv"
    write_slice(s, synthetic_slice(mat, (30.0,)))
    exr = tmp_path / "m.exr"
    rep = tmp_path / "r.json"
    assert cli.main([str(s), "--method", "fit", "--rgl", str(tmp_path / "m.bsdf"), "--preview", str(exr),
                     "--preview-renderer", "mitsuba", "--report", str(rep), "--quiet"]) == 0
    with OpenEXR.File(str(exr)) as f:
        img = f.channels()["RGB"].pixels
    h, w, _ = img.shape
    centre = img[h // 2 - 5:h // 2 + 5, w // 2 - 5:w // 2 + 5].mean(axis=(0, 1))
    assert centre[2] > centre[0] > 0  # the blue plastic, lit by the environment
    assert (tmp_path / "m.png").stat().st_size > 0
    info = json.loads(rep.read_text())["outputs"]["preview"]
    assert "Mitsuba" in info["renderer"] and info["rgl"] == str(tmp_path / "m.bsdf")


def test_missing_mitsuba_is_one_clear_line(tmp_path, capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "mitsuba", None)  # import mitsuba now raises ImportError
    s = tmp_path / "slice.csv"
    write_slice(s, synthetic_slice(Material.from_toml("configs/simulated.toml"), (30.0,)))
    assert cli.main([str(s), "--out", str(tmp_path / "m.binary"), "--preview", str(tmp_path / "m.exr"),
                     "--preview-renderer", "mitsuba"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["gonio-reconstruct: error: --preview-renderer mitsuba needs Mitsuba 3, which is not installed: "
                   "pip install 'gonio-brdf[mitsuba]' (or pip install mitsuba)"]
    assert not (tmp_path / "m.binary").exists()  # refused before any work


@pytest.mark.parametrize("argv, message", [
    (["--rgl", "m.txt"], "--rgl m.txt: expected a file name ending in .bsdf"),
    (["--export-mitsuba", "nodir/m.xml"], "--export-mitsuba nodir/m.xml: the folder nodir does not exist"),
    (["--zemax", "z.bsdf", "--zemax-azimuths", "0:90:10"], "--zemax-azimuths: a plane-symmetric grid runs from 0"),
    (["--zemax", "z.bsdf", "--zemax-radials", "5,10"], "--zemax-radials: the first radial angle must be 0"),
    (["--zemax", "z.bsdf", "--zemax-incidences", "0:x:10"], "--zemax-incidences: expected degrees as a comma"),
    (["--rgl", "a.bsdf", "--zemax", "a.bsdf"], "--rgl and --zemax name the same file a.bsdf"),
])
def test_bad_format_flags_are_one_line_before_any_work(tmp_path, capsys, monkeypatch, argv, message):
    monkeypatch.chdir(tmp_path)
    write_slice("s.csv", synthetic_slice(Material.from_toml(str(cli.Path(__file__).parents[1] / "configs" /
                                                                 "simulated.toml")), (30.0,)))
    assert cli.main(["s.csv", *argv]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0], err


def test_the_format_flags_need_no_merl_table_and_batch_refuses_them(tmp_path, capsys):
    s = tmp_path / "s.csv"
    write_slice(s, synthetic_slice(Material.from_toml("configs/simulated.toml"), (30.0,)))
    assert cli.main([str(s), "--method", "bivariate", "--rgl", str(tmp_path / "m.bsdf")]) == 0
    assert (tmp_path / "m.bsdf").exists() and not list(tmp_path.glob("*.binary"))
    assert "wrote " + str(tmp_path / "m.bsdf") in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        cli.main(["--batch", str(tmp_path), "--rgl", str(tmp_path / "x.bsdf")])
    assert e.value.code == 2
    assert "--batch takes no INPUT, --out, --preview, --report, --rgl" in capsys.readouterr().err


def test_colours_above_one_are_said_to_be_exact_and_each_export_says_what_it_cannot_carry(tmp_path):
    """Issue 41: the demo's fragment held a diffuse reflectance of 1.58 'unbounded' in a blend of weight 0.91 with
    no word (exact, but it reads as a bug), and the glTF dropped the coat's index silently."""
    from reconstruction.principled import blender, gltf, materialx
    from reconstruction.principled.model import PrincipledParams

    rec = MicrofacetReconstruction(np.array([0.3]), np.array([1.0]), "dielectric", 1.5, 0.0, np.array([0.9]),
                                   np.array([1.0]), ["value"])
    xml, info = exports.mitsuba_fragment(rec, "bright", None)
    assert info["unbounded_colours"] and info["not_carried"] == []
    assert "Colours above 1 (srgb spectra with unbounded = true) are exact, not a bug" in xml
    plain = MicrofacetReconstruction(np.array([0.3]), np.array([0.5]), "none", 1.0, 0.0, np.array([0.2]),
                                     np.array([1.0]), ["value"])
    assert "not a bug" not in exports.mitsuba_fragment(plain, "plain", None)[0]  # nothing above 1: nothing to say
    coated = PrincipledParams(base_color=(0.2, 0.2, 0.2), coat_weight=0.44, coat_ior=1.17, coat_roughness=0.4)
    entry = gltf.write_gltf(tmp_path / "c.gltf", coated, "c")
    assert entry["not_carried"] == ["coat_ior 1.17 (glTF's clearcoat has a fixed index of 1.5)"]
    assert json.loads((tmp_path / "c.gltf").read_text())["asset"]["extras"]["not_carried"] == entry["not_carried"]
    assert gltf.write_gltf(tmp_path / "d.gltf", PrincipledParams(), "d")["not_carried"] == []
    assert materialx.write_materialx(tmp_path / "c.mtlx", coated, "c")["not_carried"] == []
    assert blender.write_blender(tmp_path / "c.py", coated, "c")["not_carried"] == []
