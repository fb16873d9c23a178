"""The closest principled material (issue 27): the OpenPBR model's BRDF, its parameter ranges, the bounded fit
recovering a synthetic lambert + ggx + coat material, and ``gonio-reconstruct --principled`` end to end.
Synthetic data only; the exporters are checked by their real tools in test_principled_exports.py."""

import html
import json
import math

import numpy as np
import pytest

from reconstruction import cli
from reconstruction.core.geometry import sph_to_vec
from reconstruction.core.metrics import directional_albedo, halfvector_albedo
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice
from reconstruction.formats.slicefile import write_slice
from reconstruction.principled import albedo as alb
from reconstruction.principled.fit import cosl2, fit_principled, params_from_vector
from reconstruction.principled.model import RANGES, ParameterError, PrincipledParams
from reconstruction.synthetic import synthetic_slice

#: the synthetic truth: a coloured lambert base under a GGX specular (roughness 0.45, IOR 1.5) and a sharp coat
TRUTH = PrincipledParams(base_color=(0.6, 0.3, 0.1), specular_roughness=0.45, specular_ior=1.5, coat_weight=1.0,
                         coat_roughness=0.1, coat_ior=1.5)


def _pairs(n=4000, seed=1):
    rng = np.random.default_rng(seed)
    a = sph_to_vec(np.arccos(rng.uniform(0.05, 1, n)), rng.uniform(0, 2 * np.pi, n))
    b = sph_to_vec(np.arccos(rng.uniform(0.05, 1, n)), rng.uniform(0, 2 * np.pi, n))
    return a, b


# --- the model ---------------------------------------------------------------------------------------------------


def test_lambert_limit_and_shapes():
    wi, wo = _pairs(500)
    f = PrincipledParams(base_color=(0.2, 0.5, 0.8), specular_ior=1.0).eval(wi, wo)
    assert f.shape == (500, 3)
    np.testing.assert_allclose(f, np.broadcast_to(np.array([0.2, 0.5, 0.8]) / np.pi, f.shape), rtol=1e-12)
    below = wi.copy()
    below[:, 2] *= -1
    assert np.all(PrincipledParams().eval(below, wo) == 0.0)


def test_specular_is_the_dielectric_fresnel_ggx_lobe():
    """At the mirror direction (h = n) the specular lobe is D(0) G2 F(theta_i) / (4 cos^2): checked against the
    textbook formulas at three incidences (black base)."""
    p = PrincipledParams(base_color=(0, 0, 0), specular_roughness=0.3, specular_ior=1.5)
    th = np.radians([10.0, 40.0, 70.0])
    wi = sph_to_vec(th, np.pi)
    wo = sph_to_vec(th, 0.0)
    a = 0.3 ** 2
    mu = np.cos(th)
    lam = 0.5 * (np.sqrt(1 + a * a * (1 - mu ** 2) / mu ** 2) - 1)
    expect = (1 / (np.pi * a * a)) / (1 + 2 * lam) * alb.fresnel_dielectric(mu, 1.5) / (4 * mu * mu)
    np.testing.assert_allclose(p.eval(wi, wo)[:, 0], expect, rtol=1e-9)
    assert alb.fresnel_dielectric(np.array([1.0]), 1.5)[0] == pytest.approx(0.04, abs=1e-12)


def test_metal_f82_tint_and_energy():
    """A metal's normal-incidence reflectance is its base colour; the tint darkens it near 82 deg; a white
    lambert under a specular layer sends towards any view no more than the light it receives (albedo scaling at
    the view: the integral over the light's directions) and loses only the single-scattering microfacet
    energy."""
    c = np.array([0.9, 0.6, 0.3])
    f82 = __import__("reconstruction.principled.model", fromlist=["_f82"])._f82
    np.testing.assert_allclose(f82(np.array([1.0]), c, np.ones(3))[0], c, atol=1e-12)
    tinted = f82(np.array([math.cos(math.radians(82))]), c, np.array([0.5, 0.5, 0.5]))[0]
    untinted = f82(np.array([math.cos(math.radians(82))]), c, np.ones(3))[0]
    assert np.all(tinted < untinted)
    white = PrincipledParams(base_color=(1, 1, 1), specular_roughness=0.5)
    a = directional_albedo(lambda x, y: white.eval(y, x), np.radians([0, 30, 60, 75]))
    assert np.all(a <= 1.0 + 2e-3) and np.all(a > 0.99)  # 1 but for the table and quadrature errors
    metal = PrincipledParams(base_color=(0.9, 0.9, 0.9), base_metalness=1.0, specular_roughness=0.2)
    assert halfvector_albedo(metal.eval, np.radians([0.0]))[0, 0] == pytest.approx(0.9 * 0.99, abs=0.02)


def test_layers_are_albedo_scaled():
    """The coat takes what it reflects from the layers below: a full coat over a black base reflects the coat's
    albedo; over a white lambert, the lambert seen from the normal is scaled by 1 - that albedo."""
    coat_only = PrincipledParams(base_color=(0, 0, 0), specular_ior=1.0, coat_weight=1.0, coat_roughness=0.3,
                                 coat_ior=1.5)
    e1, s = alb.ggx_albedo(0.3, 0.04)
    expect = alb.curve(e1, np.array([1.0]))[0] * 0.04 + alb.curve(s, np.array([1.0]))[0] * 0.96
    assert halfvector_albedo(coat_only.eval, np.radians([0.0]))[0, 0] == pytest.approx(expect, rel=0.02)
    coated = PrincipledParams(base_color=(1, 1, 1), specular_ior=1.0, coat_weight=1.0, coat_roughness=0.3,
                              coat_ior=1.5)
    wi = sph_to_vec(np.radians([50.0]), 0.0)  # far from the coat's mirror direction
    wo = np.array([[0.0, 0.0, 1.0]])
    coat = coat_only.eval(wi, wo)[0, 0]
    assert coated.eval(wi, wo)[0, 0] == pytest.approx(coat + (1 - expect) / np.pi, rel=1e-3)


def test_parameter_ranges_are_enforced():
    for key, (lo, hi) in RANGES.items():
        for v in (lo - 0.5, hi + 0.5):
            bad = (0.5, v, 0.5) if key in ("base_color", "specular_color", "coat_color", "fuzz_color") else v
            with pytest.raises(ParameterError, match=key):
                PrincipledParams(**{key: bad})
    with pytest.raises(ParameterError, match="base_color"):
        PrincipledParams(base_color=(0.5, 0.5))
    with pytest.raises(ParameterError, match="specular_roughness"):
        PrincipledParams(specular_roughness=float("nan"))
    with pytest.raises(ParameterError, match="unknown"):
        PrincipledParams.from_dict({"roughness": 0.5})
    assert PrincipledParams.from_dict(TRUTH.to_dict()) == TRUTH
    # every fit vector in the box maps inside the documented ranges (the bounds of the fit)
    for x in (np.zeros(17), np.ones(17), np.random.default_rng(0).random(17)):
        params_from_vector(x)  # raises ParameterError otherwise


# --- the fit ------------------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def fitted():
    return fit_principled(TRUTH.eval)


def test_fit_recovers_a_lambert_ggx_coat_material(fitted):
    """Tolerances: colours 0.02, roughnesses 0.02, coat weight 0.05, indices 0.05 (noise-free data of the same
    model; the specular colour under a full coat is weakly determined and not asserted)."""
    p = fitted.params
    np.testing.assert_allclose(p.base_color, TRUTH.base_color, atol=0.02)
    assert p.base_metalness < 0.05 and p.base_diffuse_roughness < 0.05 and p.fuzz_weight < 0.02
    assert p.specular_roughness == pytest.approx(0.45, abs=0.02)
    assert p.specular_ior == pytest.approx(1.5, abs=0.05)
    assert p.coat_weight == pytest.approx(1.0, abs=0.05)
    assert p.coat_roughness == pytest.approx(0.1, abs=0.02)
    assert p.coat_ior == pytest.approx(1.5, abs=0.05)
    assert fitted.image_relative_rmse < 0.01 and fitted.cosl2 < 0.02
    d = fitted.to_dict()
    assert d["model"] == "OpenPBR Surface" and d["model_version"] == "1.1"
    assert set(d["error"]["image"]) == {"key", "rim"}
    assert d["summary"].startswith("a principled material reproduces this measurement to ")


def test_fit_of_an_independent_analytic_material_and_what_it_misses():
    """The project's own lobes (separable Smith, Schlick Fresnel, added rather than layered): lambert + ggx is
    close to a principled material (its roughness recovered within 0.05); a retro-reflective lobe, which no
    principled parameter describes, is named as what it misses."""
    mat = Material.from_dict({"name": "plastic", "lobes": [
        {"type": "lambert", "albedo": [0.5, 0.25, 0.1]}, {"type": "ggx", "alpha": 0.2, "specular": 1.0, "f0": 0.04}]})
    r = fit_principled(mat.eval)
    assert r.params.specular_roughness == pytest.approx(math.sqrt(0.2), abs=0.05)
    assert r.image_relative_rmse < 0.05 and r.cosl2 < 0.05
    retro = Material.from_dict({"name": "retro", "lobes": [
        {"type": "lambert", "albedo": 0.3}, {"type": "retro", "exponent": 8, "amount": 0.6}]})
    r = fit_principled(retro.eval, judge=False)
    assert r.misses == "the back-scatter towards the light", r.misses
    assert cosl2(r.params.eval, retro.eval) == pytest.approx(r.cosl2)


# --- gonio-reconstruct --------------------------------------------------------------------------------------------


def _slice(tmp_path):
    mat = Material.from_dict({"name": "blue-plastic", "lobes": [
        {"type": "lambert", "albedo": [0.05, 0.10, 0.40]},
        {"type": "ggx", "alpha": 0.15, "specular": [0.9, 0.9, 0.9], "f0": 0.04}]})
    s = synthetic_slice(mat, (30.0, 60.0))
    path = tmp_path / "slice.csv"
    write_slice(path, Slice(s.theta_i_deg, s.theta_o_deg, s.values, s.channels, 0.002 * np.abs(s.values) + 1e-6,
                            np.full(len(s), 4), 1.795e9 + np.arange(len(s)), meta={"material": "blue plastic"}))
    return path


def test_cli_principled_json_report_and_html(tmp_path, capsys):
    src = _slice(tmp_path)
    out = {k: tmp_path / f"m.{k}" for k in ("json", "mtlx", "gltf", "py")}
    code = cli.main([str(src), "--method", "fit", "--principled", str(out["json"]), "--materialx", str(out["mtlx"]),
                     "--gltf", str(out["gltf"]), "--blender", str(out["py"]), "--report", str(tmp_path / "r.json"),
                     "--html", str(tmp_path / "r.html")])
    assert code == 0  # no --out: the principled outputs are enough
    err = capsys.readouterr().err
    params = json.loads(out["json"].read_text())
    assert params["model"] == "OpenPBR Surface" and params["fitted_to"] == "the fit reconstruction"
    p = PrincipledParams.from_dict(params["parameters"])  # inside the documented ranges, or this raises
    assert p.specular_roughness == pytest.approx(math.sqrt(0.15), abs=0.05)
    assert p.base_color[2] > p.base_color[0]  # blue
    assert params["error"]["image_relative_rmse"] < 0.05 and params["error"]["cosl2"] < 0.1
    report = json.loads((tmp_path / "r.json").read_text())
    assert report["principled"]["summary"] == params["summary"]
    assert set(report["outputs"]) >= {"principled", "materialx", "gltf", "blender"}
    assert html.escape(params["summary"]) in (tmp_path / "r.html").read_text()
    assert params["summary"] in err and str(out["gltf"]) in err  # the console says it too
    assert all(out[k].stat().st_size > 0 for k in out)


def test_cli_principled_bad_outputs_exit_2(tmp_path, capsys):
    src = _slice(tmp_path)
    for flag, name, what in (("--principled", "p.txt", "ending in .json"), ("--materialx", "m.xml", ".mtlx"),
                             ("--gltf", "nodir/m.gltf", "does not exist"), ("--blender", "m.txt", ".py")):
        code = cli.main([str(src), "--method", "fit", flag, str(tmp_path / name), "--quiet"])
        err = capsys.readouterr().err
        assert code == 2 and what in err and flag in err and "Traceback" not in err
    code = cli.main([str(src), "--method", "fit", "--principled", str(tmp_path / "x.json"), "--materialx",
                     str(tmp_path / "x.json"), "--quiet"])
    assert code == 2 and not (tmp_path / "x.json").exists()
    with pytest.raises(SystemExit) as e:  # a batch names its outputs after its inputs
        cli.main(["--batch", str(tmp_path), "--principled", str(tmp_path / "p.json")])
    assert e.value.code == 2


def test_a_known_dielectric_reads_as_a_dielectric_and_a_metal_as_a_metal():
    """Issue 41: the demo's dielectric (lambert + GGX, Schlick f0 0.04 = IOR 1.5, scale 0.9) was written with
    metalness 0.16, specular_ior 1.17 and a coat of 0.44 of IOR 1.17 (image 1.8 %): parameters nobody can use.
    Metalness, coat and fuzz now stay at rest unless the plain dielectric misses by more than PLAIN_GOOD; a metal
    keeps its metalness."""
    from reconstruction.principled.fit import PLAIN_GOOD, analytic_start

    demo = Material.from_dict({"name": "demo", "lobes": [
        {"type": "lambert", "albedo": 0.14}, {"type": "ggx", "alpha": 0.15, "specular": 0.9, "f0": 0.04}]})
    start = analytic_start([{"type": "lambert", "albedo": [0.14]},
                            {"type": "ggx", "alpha": 0.15, "ior": 1.5, "f0": 0.04, "specular": [0.9]}])
    assert start is not None and start[3] == 0.0 and start[10] == 0.0
    r = fit_principled(demo.eval, start=start)
    p = r.params
    assert p.base_metalness < 0.01 and p.coat_weight < 0.01 and p.fuzz_weight < 0.01
    assert 1.35 < p.specular_ior < 1.6 and p.specular_roughness == pytest.approx(math.sqrt(0.15), abs=0.03)
    assert r.image_relative_rmse < PLAIN_GOOD
    assert r.layers["layers"] == "at rest" and r.layers["image_relative_rmse_with_layers"] < r.image_relative_rmse
    assert r.to_dict()["layers"] == r.layers
    # the plain dielectric is polished by the image error: 4.7 % straight from the compressed fit, 3.5 % after
    assert r.image_relative_rmse < 0.04
    # nothing is lost: the layered candidate's parameters are in the JSON, and the summary says what they buy
    other = PrincipledParams.from_dict(r.layers["parameters_with_layers"])
    assert other.base_metalness > 0.05 or other.coat_weight > 0.05
    assert "written as a plain dielectric" in r.sentence and f"{r.layers['image_relative_rmse_with_layers']:.1%}" \
        in r.sentence
    metal = PrincipledParams(base_color=(0.9, 0.6, 0.3), base_metalness=1.0, specular_roughness=0.3)
    m = fit_principled(metal.eval, judge=False)
    assert m.params.base_metalness > 0.9
    assert analytic_start([{"type": "lambert", "albedo": [0.2]}, {"type": "retro", "exponent": 8}]) is None
