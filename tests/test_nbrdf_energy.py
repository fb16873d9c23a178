"""The nbrdf lobe (neural BRDFs in the published npy layout) and the tabulated lobe albedos of
reconstruction.core.energy."""

import math

import numpy as np
import pytest

from reconstruction.core.energy import microfacet_albedo, retro_albedo
from reconstruction.core.geometry import half_diff_from_dirs, sph_to_vec
from reconstruction.core.metrics import directional_albedo
from reconstruction.core.models import Colour, Material, MaterialError, Microfacet, Retro
from reconstruction.synthetic import synthetic_slice

SHAPES = {"fc1": (6, 21), "b1": (21,), "fc2": (21, 21), "b2": (21,), "fc3": (21, 3), "b3": (3,)}


def write_nbrdf(prefix, seed=0):
    rng = np.random.default_rng(seed)
    w = {k: rng.normal(0, 0.4, s) for k, s in SHAPES.items()}
    for k, a in w.items():
        np.save(f"{prefix}_{k}.npy", a)
    return w


def reference(w, wi, wo):
    """The published evaluation, written out step by step for one direction pair at a time."""
    out = []
    for a, b in zip(wi, wo, strict=True):
        th, _, td, pd = (float(x) for x in half_diff_from_dirs(a, b))
        pd = pd + math.pi if pd < 0 else pd
        x = np.array([math.sin(th), 0.0, math.cos(th), math.sin(td) * math.cos(pd), math.sin(td) * math.sin(pd),
                      math.cos(td)])
        h1 = np.maximum(x @ w["fc1"] + w["b1"], 0)
        h2 = np.maximum(h1 @ w["fc2"] + w["b2"], 0)
        out.append(np.maximum(np.exp(h2 @ w["fc3"] + w["b3"]) - 1.0, 0.0))
    return np.array(out)


def test_nbrdf_lobe_evaluates_the_published_network(tmp_path):
    w = write_nbrdf(tmp_path / "mat")
    toml = tmp_path / "m.toml"
    toml.write_text('[material]\nname = "n"\n[[material.lobes]]\ntype = "nbrdf"\npath = "mat"\nscale = 2.0\n')
    m = Material.from_toml(toml)  # the prefix resolves relative to the TOML file
    assert m.n_channels == 3
    rng = np.random.default_rng(3)
    wi = sph_to_vec(np.arccos(rng.uniform(0.05, 1, 50)), rng.uniform(0, 2 * np.pi, 50))
    wo = sph_to_vec(np.arccos(rng.uniform(0.05, 1, 50)), rng.uniform(0, 2 * np.pi, 50))
    np.testing.assert_allclose(m.eval(wi, wo), 2.0 * reference(w, wi, wo), rtol=1e-12, atol=1e-15)
    # reciprocal and isotropic by the phi_d fold, zero below the horizon
    np.testing.assert_allclose(m.eval(wo, wi), m.eval(wi, wo), rtol=1e-9, atol=1e-15)
    assert np.all(m.eval(wi, wo * np.array([1, 1, -1])) == 0)
    # a material made of it can be sliced like any other
    s = synthetic_slice(m, (30.0,))
    assert s.channels == ["R", "G", "B"] and np.all(np.isfinite(s.values))


def test_nbrdf_errors_name_the_file(tmp_path):
    write_nbrdf(tmp_path / "mat")
    (tmp_path / "mat_fc2.npy").unlink()
    with pytest.raises(MaterialError, match="mat_fc2.npy: no such file"):
        Material.from_dict({"lobes": [{"type": "nbrdf", "path": "mat"}]}, base_dir=tmp_path)
    np.save(tmp_path / "mat_fc2.npy", np.zeros((20, 21)))
    with pytest.raises(MaterialError, match=r"shape \(21, 21\)"):
        Material.from_dict({"lobes": [{"type": "nbrdf", "path": "mat"}]}, base_dir=tmp_path)


@pytest.mark.parametrize("alpha, f0, dist", [(0.3, None, "ggx"), (0.3, 0.04, "ggx"), (0.6, 0.5, "beckmann"),
                                             (1.0, None, "beckmann")])
def test_microfacet_albedo_matches_a_hemisphere_quadrature(alpha, f0, dist):
    lobe = Microfacet(colour=Colour(np.ones(1)), alpha=alpha, f0=f0, distribution=dist)
    ti = np.radians([0.0, 30.0, 60.0, 80.0])
    ref = directional_albedo(lambda a, b: lobe.eval(a, b), ti, 400, 400)[:, 0]
    np.testing.assert_allclose(microfacet_albedo(ti, alpha, f0, dist), ref, rtol=0.01, atol=1e-3)


def test_narrow_lobe_albedo_is_its_fresnel_reflectance():
    # alpha = 1e-3: the lobe is a mirror, its albedo is F(theta_i) (G ~ 1); no fixed grid could resolve it
    ti = np.radians([0.0, 40.0, 70.0, 80.0])
    f = 0.04 + 0.96 * (1 - np.cos(ti)) ** 5
    np.testing.assert_allclose(microfacet_albedo(ti, 1e-3, 0.04), f, rtol=0.01)


@pytest.mark.parametrize("n", [1.0, 10.0, 200.0])
def test_retro_albedo_matches_a_hemisphere_quadrature(n):
    lobe = Retro(colour=Colour(np.ones(1)), exponent=n)
    ti = np.radians([0.0, 30.0, 60.0, 80.0])
    ref = directional_albedo(lambda a, b: lobe.eval(a, b), ti, 400, 400)[:, 0]
    np.testing.assert_allclose(retro_albedo(ti, n), ref, rtol=0.01, atol=2e-3)
