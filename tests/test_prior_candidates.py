"""The candidate priors of issue 40 on synthetic materials only: the local prior's neighbours, the kernel blend and
the structured (factor) prior (reconstruction.methods.prior_local, prior_structured)."""

from __future__ import annotations

import numpy as np
import pytest

from reconstruction.core.geometry import inplane_to_dirs
from reconstruction.core.slicedata import Slice
from reconstruction.methods import prior as P
from reconstruction.methods import prior_local as L
from reconstruction.methods import prior_structured as S


def _ggx(wi: np.ndarray, wo: np.ndarray, kd: np.ndarray, ks: float, alpha: float, f0: float = 0.05) -> np.ndarray:
    """f_r (n, 3) of a Lambert + GGX material (V-cavity shadowing, Schlick's Fresnel)."""
    h = wi + wo
    h /= np.linalg.norm(h, axis=1, keepdims=True)
    ci, co, ch = (np.clip(v, 1e-6, 1.0) for v in (wi[:, 2], wo[:, 2], h[:, 2]))
    cd = np.clip(np.sum(wi * h, axis=1), 1e-6, 1.0)
    a2 = alpha**2
    d = a2 / (np.pi * (ch**2 * (a2 - 1.0) + 1.0) ** 2)
    g = np.minimum(1.0, np.minimum(2 * ch * co / cd, 2 * ch * ci / cd))
    spec = ks * d * (f0 + (1 - f0) * (1 - cd) ** 5) * g / (4 * ci * co)
    return np.asarray(kd)[None, :] / np.pi + spec[:, None]


def _slice(f, incidences=(40.0,)) -> Slice:
    to = np.arange(-80.0, 80.0 + 1e-9, 2.0)
    a = np.concatenate([np.full(int(np.sum(np.abs(to + t) >= 4)), t) for t in incidences])
    b = np.concatenate([to[np.abs(to + t) >= 4] for t in incidences])
    wi, wo = inplane_to_dirs(np.radians(a), np.radians(b))
    return Slice(a, b, f(wi, wo), ["R", "G", "B"])


GLOSSY = [(np.array([0.02, 0.03, 0.05]) * (1 + 0.1 * i), 1.0, a) for i, a in enumerate(np.linspace(0.05, 0.12, 8))]
MATTE = [(np.array([0.5, 0.4, 0.3]) * (1 - 0.05 * i), 0.1, a) for i, a in enumerate(np.linspace(0.35, 0.6, 8))]


@pytest.fixture(scope="module")
def two_families() -> P.PriorSet:
    """8 glossy (GGX alpha 0.05-0.12, dark diffuse) and 8 matte (alpha 0.35-0.6, bright diffuse) materials."""
    g = P._grid()
    wi, wo = g["wi"][g["train"]], g["wo"][g["train"]]
    tables = np.stack([_ggx(wi, wo, kd, ks, a).T for kd, ks, a in GLOSSY + MATTE]).astype(np.float32)
    names = [f"glossy{i}" for i in range(len(GLOSSY))] + [f"matte{i}" for i in range(len(MATTE))]
    return P.PriorSet("synthetic", names, tables)


@pytest.mark.parametrize("family,kd,ks,alpha", [("glossy", [0.03, 0.04, 0.06], 1.0, 0.085),
                                                ("matte", [0.45, 0.35, 0.3], 0.1, 0.45)])
def test_local_prior_picks_the_family_of_the_sample(two_families, family, kd, ks, alpha):
    s = _slice(lambda wi, wo: _ggx(wi, wo, np.array(kd), ks, alpha))
    rec = L.reconstruct_local(s, two_families, n_near=6)
    near = rec.info["prior"]["local"]["nearest"]
    assert len(near) == 6 and all(n.startswith(family) for n in near), near
    assert rec.method == "prior" and rec.info["prior"]["materials"] == 6
    # and the local basis completes an incidence it did not see: the in-plane row at 65 deg within 25 % (f cos cos)
    ti, to = np.full(60, 65.0), np.linspace(-78, 78, 60)
    wi, wo = inplane_to_dirs(np.radians(ti), np.radians(to))
    truth, got = _ggx(wi, wo, np.array(kd), ks, alpha), rec.eval(wi, wo)
    cc = (wi[:, 2] * wo[:, 2])[:, None]
    assert np.sqrt(np.sum(((got - truth) * cc) ** 2) / np.sum((truth * cc) ** 2)) < 0.25


def test_the_blend_of_a_family_member_stays_in_its_family(two_families):
    s = _slice(lambda wi, wo: _ggx(wi, wo, np.array([0.5, 0.4, 0.3]), 0.1, 0.5))  # matte4-like
    rec = L.reconstruct_blend(s, two_families, exclude=("matte5",), n_near=4, tau=0.3)
    g = P._grid()
    wi, wo = g["wi"][g["inplane"]], g["wo"][g["inplane"]]
    truth = _ggx(wi, wo, np.array([0.5, 0.4, 0.3]), 0.1, 0.5)
    got = rec.eval(wi, wo)
    assert np.median(np.abs(np.log(got / truth))) < 0.1  # a glossy member would be off by a factor of 10


def _factors(kd: float, alpha: float, f0: float) -> np.ndarray:
    """The structured model's factors (absolute scale) of a Lambert + GGX (Schlick) material."""
    a = np.full(S.NA, np.log(kd / np.pi))
    th = S.KNOTS_H**2 * np.pi / 2
    a2 = alpha**2
    d = np.log(a2 / (np.pi * (np.cos(th) ** 2 * (a2 - 1) + 1) ** 2) / 4.0 * f0)
    fr = f0 + (1 - f0) * (1 - np.cos(np.radians(S.KNOTS_D))) ** 5
    return np.concatenate([a, d, np.log(fr[1:] / f0)])


def test_structured_prior_recovers_the_factors_of_a_microfacet_material_from_one_slice():
    rng = np.random.default_rng(1)
    rows = np.stack([_factors(rng.uniform(0.05, 0.5), rng.uniform(0.08, 0.5), rng.uniform(0.03, 0.2))
                     for _ in range(60)])
    sp = S.StructuredPrior([f"m{i}" for i in range(60)], np.repeat(rows[:, None], 3, axis=1), np.ones((60, 3)))
    truth = _factors(0.2, 0.18, 0.1)

    def f(wi, wo):
        ft = S.features(wi, wo)
        return np.repeat(((np.exp(S.model_mapped(truth, ft)) - P.EPS) / ft.cc)[:, None], 3, axis=1)

    s = _slice(f)
    rec = S.reconstruct_structured(s, sp)
    got = np.asarray(rec.info["factors"])[1]
    wi, wo = inplane_to_dirs(np.radians(s.theta_i_deg), np.radians(s.theta_o_deg))
    scale = P.channel_scales((f(wi, wo)[:, 1] * wi[:, 2] * wo[:, 2])[None])[0]
    got[: S.NA + S.NH] += np.log(scale)  # back to the absolute scale
    a, d, fr = got[: S.NA], got[S.NA:S.NA + S.NH], got[S.NA + S.NH:]
    ta, td, tf = truth[: S.NA], truth[S.NA:S.NA + S.NH], truth[S.NA + S.NH:]
    lobe = S.KNOTS_H <= 0.3  # theta_h up to 8 deg: where the microfacet part dominates
    assert np.max(np.abs(d[lobe] - td[lobe])) < 0.1
    assert np.max(np.abs(a[:4] - ta[:4])) < 0.1  # the diffuse level over theta_d 0-55 deg, which the slice sees
    assert np.max(np.abs(fr[:2] - tf[:2])) < 0.15  # the Fresnel-like factor at theta_d 20 and 40 deg
    mu = sp.factors[:, 1].mean(axis=0)
    assert np.max(np.abs(mu[S.NA:S.NA + S.NH][lobe] - td[lobe])) > 0.5  # not the prior's mean handed back
    # and the table at an incidence the slice did not see (70 deg in-plane) follows the truth
    ti, to = np.full(40, 70.0), np.linspace(-78, 78, 40)
    wi, wo = inplane_to_dirs(np.radians(ti), np.radians(to))
    cc = (wi[:, 2] * wo[:, 2])[:, None]
    err = np.sqrt(np.sum(((rec.eval(wi, wo) - f(wi, wo)) * cc) ** 2) / np.sum((f(wi, wo) * cc) ** 2))
    assert err < 0.2


def test_method_prior_takes_the_local_basis_as_an_option(tmp_path, monkeypatch):
    """``--method prior --prior-near N`` (pipeline option ``prior_near``) completes from the N nearest materials."""
    from reconstruction import pipeline
    from reconstruction.methods import Options

    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    folder = tmp_path / "prior"
    folder.mkdir()
    for k, (fam, alb, al) in enumerate([("glossy", 0.05, 0.06), ("glossy", 0.08, 0.09), ("glossy", 0.06, 0.12),
                                         ("matte", 0.5, 0.4), ("matte", 0.6, 0.5), ("matte", 0.4, 0.6)]):
        (folder / f"{fam}{k}.toml").write_text(
            f'[material]\nname = "{fam}{k}"\n[[material.lobes]]\ntype = "lambert"\nalbedo = {alb}\n'
            f'[[material.lobes]]\ntype = "ggx"\nalpha = {al}\nspecular = 0.9\nf0 = 0.04\n', encoding="utf-8")
    s = _slice(lambda wi, wo: _ggx(wi, wo, np.array([0.07, 0.07, 0.07]), 1.0, 0.1))
    rec, _ = pipeline.reconstruct(s, "prior", Options(prior=str(folder), prior_near=3))
    assert sorted(rec.info["prior"]["local"]["nearest"]) == ["glossy0", "glossy1", "glossy2"]
    rec, _ = pipeline.reconstruct(s, "prior", Options(prior=str(folder)))
    assert "local" not in rec.info["prior"] and rec.info["prior"]["materials"] == 6
