"""--method prior: a full BRDF completed from a basis of measured materials (synthetic prior folders here; the
real materials are judged by benchmarks/bench_real_materials.py)."""

import itertools
import json
import subprocess
import sys

import numpy as np
import pytest

from reconstruction import pipeline
from reconstruction.base import ReconstructionError
from reconstruction.core import merlgrid, merltable
from reconstruction.core.metrics import relative_rmse_cos
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice
from reconstruction.formats.slicefile import write_slice
from reconstruction.methods import Options, auto, prior
from reconstruction.synthetic import synthetic_slice

TARGET = Material.from_dict({"name": "target", "lobes": [
    {"type": "lambert", "albedo": [0.4, 0.25, 0.1]}, {"type": "ggx", "alpha": 0.18, "specular": 0.9, "f0": 0.04}]})


def write_family(folder, n_alpha=(0.06, 0.12, 0.25, 0.5)):
    """A prior folder of material TOML files: lambert + ggx over albedo, colour and roughness."""
    folder.mkdir(parents=True, exist_ok=True)
    for k, (a, al, col) in enumerate(itertools.product((0.1, 0.3, 0.6), n_alpha, ((1, 1, 1), (1, 0.5, 0.2)))):
        alb = [round(a * c, 3) for c in col]
        (folder / f"m{k:02d}.toml").write_text(
            f'[material]\nname = "m{k}"\n[[material.lobes]]\ntype = "lambert"\nalbedo = {alb}\n'
            f'[[material.lobes]]\ntype = "ggx"\nalpha = {al}\nspecular = 0.9\nf0 = 0.04\n', encoding="utf-8")
    return folder


@pytest.fixture(scope="module")
def family(tmp_path_factory):
    cache = tmp_path_factory.mktemp("cache")
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CACHE_HOME", str(cache))
    prior._load_cached.cache_clear()
    folder = write_family(tmp_path_factory.mktemp("prior") / "materials")
    yield folder, cache
    mp.undo()


@pytest.fixture(scope="module")
def truth():
    return merltable.tabulate(TARGET.eval)


def test_a_material_of_the_family_comes_back_from_one_and_from_three_slices(family, truth):
    folder, _ = family
    errs = {}
    for inc in ((40.0,), (20.0, 40.0, 60.0)):
        s = synthetic_slice(TARGET, inc)
        rec = prior.reconstruct_prior(s, folder)
        errs[inc] = relative_rmse_cos(rec.table(), truth, 80)
        biv = relative_rmse_cos(pipeline.tabulate(pipeline.reconstruct(s, "bivariate")[0]), truth, 80)
        assert errs[inc] < 0.5 * biv, (inc, errs[inc], biv)  # the family's structure completes the slice
        rep = rec.report()
        assert rep["method"] == "prior" and rep["prior"]["materials"] == 24
        assert rep["parameters"]["components"] == list(prior.K_CHOICES)
        assert rep["residuals"]["relative_rmse_cos_own_samples"] < 0.1
    assert errs[(40.0,)] < 0.2 and errs[(20.0, 40.0, 60.0)] < 0.1, errs
    # eval agrees with the table it writes (the same interpolation), and is zero below the horizon
    wi = np.array([[-0.5, 0.0, np.sqrt(0.75)], [0.0, 0.0, 1.0], [0.3, 0.1, -0.9]])
    wo = np.array([[0.5, 0.0, np.sqrt(0.75)], [0.2, 0.3, 0.93], [0.0, 0.0, 1.0]])
    v = rec.eval(wi, wo)
    assert v.shape == (3, 3) and np.all(v[:2] > 0) and np.all(v[2] == 0)
    np.testing.assert_allclose(v[:2], merltable.lookup(rec.table(), wi[:2], wo[:2], interpolate=True), rtol=0.1)


def test_a_grey_slice_gives_a_grey_table(family):
    s = synthetic_slice(TARGET, (40.0,))
    g = Slice(s.theta_i_deg, s.theta_o_deg, s.values.mean(axis=1, keepdims=True), ["value"])
    rec = prior.reconstruct_prior(g, family[0])
    t = rec.table()
    assert rec.channels == ["value"] and t.shape == merltable.SHAPE
    np.testing.assert_array_equal(t[0], t[2])


def test_the_prior_is_cached_and_a_changed_folder_is_tabulated_again(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    folder = write_family(tmp_path / "p", n_alpha=(0.1, 0.3))
    prior._load_cached.cache_clear()
    a = prior.load_prior(folder)
    files = list((tmp_path / "cache" / "gonio-brdf").glob("prior-*.npz"))
    assert len(files) == 1 and a.tables.shape == (12, 3, int(prior._grid()["train"].sum()))  # the training cells
    # coded (reconstruction.methods.priorcodec): a fraction of the float32 tables' size
    assert files[0].stat().st_size < 0.25 * a.tables.nbytes
    prior._load_cached.cache_clear()
    b = prior.load_prior(folder)  # read from the cache: the same values
    np.testing.assert_array_equal(a.tables, b.tables)
    (folder / "m00.toml").write_text('[material]\nname = "x"\n[[material.lobes]]\ntype = "lambert"\nalbedo = 0.9\n'
                                     '\n', encoding="utf-8")
    prior._load_cached.cache_clear()
    c = prior.load_prior(folder)
    assert len(list((tmp_path / "cache" / "gonio-brdf").glob("prior-*.npz"))) == 2
    assert not np.array_equal(a.tables[0], c.tables[0]) and np.array_equal(a.tables[1], c.tables[1])


def test_leave_one_out_and_too_small_priors(family):
    folder, _ = family
    s = synthetic_slice(TARGET, (40.0,))
    rec = prior.reconstruct_prior(s, folder, exclude=("m00", "m01", "nope"))
    assert rec.report()["prior"]["excluded"] == ["m00", "m01"] and rec.report()["prior"]["materials"] == 22
    names = prior.load_prior(folder).names
    with pytest.raises(ReconstructionError, match="at least 2 materials"):
        prior.reconstruct_prior(s, folder, exclude=tuple(names[1:]))


def test_bad_prior_folders_are_one_clear_line(tmp_path):
    s = synthetic_slice(TARGET, (40.0,))
    with pytest.raises(ReconstructionError, match="not a folder"):
        prior.reconstruct_prior(s, tmp_path / "missing")
    (tmp_path / "empty").mkdir()
    with pytest.raises(ReconstructionError, match="0 material"):
        prior.reconstruct_prior(s, tmp_path / "empty")
    bad = tmp_path / "bad"
    bad.mkdir()
    for k in range(2):
        (bad / f"b{k}.toml").write_text('[material]\nname = "b"\n[[material.lobes]]\ntype = "nosuch"\n', "utf-8")
    with pytest.raises(ReconstructionError, match="material b0"):
        prior.reconstruct_prior(s, bad)


def _cli(*args, env=None):
    return subprocess.run([sys.executable, "-m", "reconstruction.cli", *map(str, args)], capture_output=True,
                          text=True, timeout=300, env=env)


@pytest.mark.slow
def test_gonio_reconstruct_with_a_prior_and_auto_trying_it(family, tmp_path):
    import os

    folder, cache = family
    env = {**os.environ, "XDG_CACHE_HOME": str(cache)}
    s = synthetic_slice(TARGET, (40.0,))
    src = tmp_path / "slice.csv"
    write_slice(src, Slice(s.theta_i_deg, s.theta_o_deg, s.values, s.channels, 0.002 * s.values + 1e-6,
                           np.full(len(s), 4), 1.795e9 + np.arange(len(s)), meta={"material": "t"}))
    r = _cli(src, "--method", "prior", "--out", tmp_path / "m.binary", env=env)
    assert r.returncode == 2 and "Traceback" not in r.stderr
    assert len(r.stderr.strip().splitlines()) == 1 and "--prior DIR" in r.stderr
    # the two successful --method prior runs in this process (main(argv): the same command line, the prior already
    # tabulated here; the module's fixture points XDG_CACHE_HOME at the same cache); the refusals and auto below
    # are whole processes
    from reconstruction.cli import main

    assert main([str(a) for a in (src, "--method", "prior", "--prior", folder, "--out", tmp_path / "m.binary",
                                  "--report", tmp_path / "m.json", "--quiet")]) == 0
    rep = json.loads((tmp_path / "m.json").read_text())
    assert rep["method"] == "prior" and rep["details"]["prior"]["materials"] == 24 and "anchor" not in rep["details"]
    assert main([str(a) for a in (src, "--method", "prior", "--prior", folder, "--prior-anchor", "0.25", "--out",
                                  tmp_path / "m.binary", "--report", tmp_path / "m.json", "--quiet")]) == 0
    assert json.loads((tmp_path / "m.json").read_text())["details"]["anchor"]["weight"] == 0.25
    r = _cli(src, "--method", "prior", "--prior", folder, "--prior-anchor", "2", "--out", tmp_path / "m.binary",
             env=env)
    assert r.returncode == 2 and "--prior-anchor: expected a number from 0 to 1, got '2'" in r.stderr
    r = _cli(src, "--prior", folder, "--out", tmp_path / "a.binary", "--report", tmp_path / "a.json", env=env)
    assert r.returncode == 0, r.stderr
    cv = json.loads((tmp_path / "a.json").read_text())["cross_validation"]
    assert "prior" in {c["method"] for c in cv["scores"]}
    assert cv["single_incidence_preference"] == {"method": "prior", "methods": ["prior"],
                                                 "margin": auto.PRIOR_MARGIN_SINGLE}
    assert cv["chosen"] == "fit"  # the family's exact lambert + ggx predicts the held-out samples ~1e-9


def test_auto_prefers_the_prior_by_its_margins_and_an_exact_model_still_wins():
    from reconstruction.methods.crossval import CVScore

    sc = [CVScore("fit", 0.01, [], 0.0), CVScore("bivariate", 0.019, [], 0.0), CVScore("prior", 0.035, [], 0.0)]
    order = lambda pref: [c.method for c in auto.rank(sc, *pref)]  # noqa: E731
    with_prior = ["fit", "microfacet", "bivariate", "revolve", "prior"]
    # one slice: prior within 4x of the best is chosen; several: within 2x only (so it passes bivariate, 1.9x)
    assert auto.preference(with_prior, True) == (["prior"], auto.PRIOR_MARGIN_SINGLE)
    assert order(auto.preference(with_prior, True))[0] == "prior"
    assert auto.preference(with_prior, False) == (["prior"], auto.PRIOR_MARGIN_SEVERAL)
    assert order(auto.preference(with_prior, False)) == ["fit", "prior", "bivariate"]
    # without a prior: the plain held-out order from one slice and from several
    assert order(auto.preference(with_prior[:4], True)) == ["fit", "bivariate", "prior"]
    assert order(auto.preference(with_prior[:4], False)) == ["fit", "bivariate", "prior"]
    # an exact model predicts far better than any margin (the CLI test below: fit is chosen with the prior there)
    exact = [CVScore("fit", 1e-9, [], 0.0), CVScore("prior", 0.02, [], 0.0)]
    assert auto.rank(exact, *auto.preference(with_prior, True))[0].method == "fit"
    # ... unless the best predicts to within NOISE_LEVEL_FACTOR of the samples' own noise: then the plain order
    assert auto.rank(sc, ["prior"], 4.0, noise=0.008)[0].method == "fit"  # 0.01 <= 1.5 x 0.008
    assert auto.rank(sc, ["prior"], 4.0, noise=0.005)[0].method == "prior"


def test_the_noise_level_is_what_the_samples_std_amounts_to():
    from reconstruction.methods.crossval import noise_level

    assert noise_level(synthetic_slice(TARGET, (40.0,))) == 0.0
    assert 0.009 < noise_level(synthetic_slice(TARGET, (40.0,), noise=0.01, seed=3)) < 0.011


@pytest.mark.slow
def test_auto_with_a_prior_keeps_an_exact_model_of_a_noisy_slice(family, truth):
    s = synthetic_slice(TARGET, (40.0,), noise=0.01, seed=1)
    rec, choice = pipeline.reconstruct(s, "auto", Options(prior=str(family[0])))
    pref = choice["cross_validation"]["preference"]
    assert pref["methods"] == ["prior"] and pref["applied"] is False and 0.009 < pref["noise_level"] < 0.011
    assert choice["used"] == "fit" and "samples' own noise" in choice["reason"]
    assert relative_rmse_cos(pipeline.tabulate(rec), truth, 80) < 0.05


@pytest.mark.slow
def test_an_anchored_prior_is_the_weighted_geometric_mean_of_prior_and_bivariate(family):
    from reconstruction import methods
    from reconstruction.core.checks import checked_albedo
    from reconstruction.core.geometry import inplane_to_dirs

    folder, _ = family
    s = synthetic_slice(TARGET, (40.0,))
    opts = lambda a: Options(prior=str(folder), prior_anchor=a)  # noqa: E731
    p, b = methods.get("prior").build(s, opts(0.0), None), methods.get("bivariate").build(s, opts(0.0), None)
    rec = methods.get("prior").build(s, opts(0.5), None)
    assert isinstance(rec, prior.AnchoredPrior) and rec.method == "prior" and rec.channels == ["R", "G", "B"]
    rng = np.random.default_rng(4)
    wi, wo = inplane_to_dirs(np.radians(rng.uniform(0, 80, 50)), np.radians(rng.uniform(-80, 80, 50)))
    wo = wo @ np.array([[np.cos(0.7), -np.sin(0.7), 0], [np.sin(0.7), np.cos(0.7), 0], [0, 0, 1]])  # off-plane
    np.testing.assert_allclose(rec.eval(wi, wo), np.sqrt(p.eval(wi, wo) * b.eval(wi, wo)), rtol=1e-12)
    np.testing.assert_allclose(rec.eval(wi, wo), rec.eval(wo, wi), rtol=1e-9)  # reciprocal as both are
    valid = merlgrid.valid_mask()[None] & np.ones((3, 1, 1, 1), dtype=bool)
    t = rec.table()
    np.testing.assert_allclose(t[valid], np.sqrt(p.table() * np.nan_to_num(b.table()))[valid], rtol=1e-12)
    assert np.all(t[~valid] == 0)
    # directional albedo at most that of the brighter of the two (AM-GM, cell by cell)
    alb = [checked_albedo(r.eval, 32, 64)[0].max() for r in (rec, p, b)]
    assert alb[0] <= max(alb[1:]) + 1e-9, alb
    rep = rec.report()
    assert rep["anchor"]["weight"] == 0.5 and rep["anchor"]["to"] == "bivariate" and rep["prior"]["materials"] == 24
    # anchor 1 is the bivariate interpolation itself; a weight outside 0..1 is refused with one line
    np.testing.assert_allclose(methods.get("prior").build(s, opts(1.0), None).table()[valid],
                               np.nan_to_num(b.table())[valid], rtol=1e-12)
    with pytest.raises(ReconstructionError, match=r"--prior-anchor 1\.5: expected a weight from 0"):
        methods.get("prior").build(s, opts(1.5), None)


def test_held_out_predictions_are_scored_as_the_relative_rmse_of_f_cos_cos():
    from reconstruction.core.geometry import inplane_to_dirs
    from reconstruction.methods.crossval import folds, score_predictions

    s = synthetic_slice(TARGET, (20.0, 40.0, 60.0)).sorted()
    _, masks = folds(s)
    f, _ = s.brdf()
    wi, wo = inplane_to_dirs(np.radians(s.theta_i_deg), np.radians(s.theta_o_deg))
    c = (wi[:, 2] * wo[:, 2])[:, None]
    pred = f * np.random.default_rng(2).uniform(0.7, 1.3, f.shape)
    for inside in (None, np.abs(s.theta_o_deg) < 45):  # all held-out samples, or those inside a scene's range
        sc = score_predictions(s, "x", pred, masks, inside)
        use = np.ones(len(s), dtype=bool) if inside is None else inside
        per = [np.sqrt(np.sum(((pred - f) * c)[m & use] ** 2) / np.sum((f * c)[m & use] ** 2)) for m in masks]
        pooled = np.sqrt(np.sum(((pred - f) * c)[use] ** 2) / np.sum((f * c)[use] ** 2))  # the folds cover all
        assert sc.error == pytest.approx(pooled, rel=1e-12) and sc.fold_errors == pytest.approx(per, rel=1e-12)
    assert score_predictions(s, "x", f, masks).error == 0.0
    holes = pred.copy()
    holes[masks[1]] = np.nan  # a fold without predictions is a failure, not a silently smaller score
    bad = score_predictions(s, "x", holes, masks)
    assert np.isinf(bad.error) and "fold 2" in bad.failure


@pytest.mark.slow
def test_auto_anchors_the_prior_on_a_material_outside_its_family(family):
    """PHONG (Oren-Nayar + Phong) is unlike every lambert + ggx of the prior: the prior alone overshoots from one
    slice; auto scores the anchored variants from held-out predictions and takes the best of them."""
    from test_cli_reconstruct import PHONG

    from reconstruction.methods.crossval import folds, score_predictions
    from reconstruction.methods.prior import anchored

    folder, _ = family
    s = synthetic_slice(PHONG, (40.0,))
    rec, choice = pipeline.reconstruct(s, "auto", Options(prior=str(folder)))
    cv = choice["cross_validation"]
    variants = {c["label"]: c for c in cv["scores"] if c["method"] == "prior"}
    assert set(variants) == {"prior"} | {f"prior (anchor {a:g})" for a in auto.PRIOR_ANCHORS}
    best = min(variants.values(), key=lambda c: c["held_out_relative_rmse_cos"])
    assert choice["used"] == "prior" and cv["chosen_label"] == best["label"] != "prior"
    assert cv["prior_anchor"] == best["prior_anchor"] > 0 and best["label"] in choice["reason"]
    assert rec.report()["anchor"]["weight"] == best["prior_anchor"]
    # --prior-anchor is for --method prior: auto scores and builds its own anchors whatever it says
    rec1, choice1 = pipeline.reconstruct(s, "auto", Options(prior=str(folder), prior_anchor=1.0))
    got = {c["label"]: c["held_out_relative_rmse_cos"] for c in choice1["cross_validation"]["scores"]}
    assert got == pytest.approx({c["label"]: c["held_out_relative_rmse_cos"] for c in cv["scores"]}, rel=1e-6)
    assert rec1.report()["anchor"]["weight"] == best["prior_anchor"]
    # the variants' scores are those of the blend of prior's and bivariate's own held-out predictions
    from reconstruction import methods
    from reconstruction.methods.crossval import cross_validate

    ss = s.sorted()
    _, masks = folds(ss)
    cvs = {m: cross_validate(ss, m, lambda tr, m=m: methods.get(m).build(tr, Options(prior=str(folder)),
                                                                          None), masks) for m in ("prior", "bivariate")}
    for a in auto.PRIOR_ANCHORS:
        blend = score_predictions(ss, "prior", anchored(cvs["prior"].predictions, cvs["bivariate"].predictions, a),
                                  masks)
        assert blend.error == pytest.approx(variants[f"prior (anchor {a:g})"]["held_out_relative_rmse_cos"], rel=1e-9)
    np.testing.assert_allclose(choice["held_out_predictions"]["prior"],  # the chosen variant's predictions
                               anchored(cvs["prior"].predictions, cvs["bivariate"].predictions, best["prior_anchor"]))
    truth = merltable.tabulate(PHONG.eval)
    plain = pipeline.reconstruct(s, "prior", Options(prior=str(folder)))[0]
    err, err_plain = (relative_rmse_cos(pipeline.tabulate(r), truth, 80) for r in (rec, plain))
    assert err < 0.5 * err_plain, (err, err_plain)  # 0.58 against 1.65


def test_a_basis_of_every_material_is_the_same_made_once_or_from_the_kept_products():
    """basis(): a run's one basis of every material makes f cos cos as its own array (no cache), a second call and a
    leave-one-out call read the kept products; the numbers are the same either way, and the residual projected in
    chunks of cells equals the whole product."""
    rng = np.random.default_rng(3)
    g = prior._grid()
    m = int(g["train"].sum())
    n = 14  # 42 rows: more than the basis's 30 components, a residual left
    tables = rng.uniform(0.01, 2.0, (n, 3, m)).astype(np.float32)
    idx = rng.integers(0, m, (40, 2))
    w = np.full((40, 2), 0.5)
    fresh = prior.PriorSet("t", [f"m{k}" for k in range(n)], tables)
    a = fresh.basis(idx, w, residual=True)  # no cache yet: its own product
    assert fresh._fc_cache is None
    kept = prior.PriorSet("t", [f"m{k}" for k in range(n)], tables)
    kept._fc()  # the products kept: every call copies its rows
    b = kept.basis(idx, w, residual=True)
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)
    mu, comps, _, resvar, at_samples, rows_coef = a
    fc = tables.reshape(-1, m) * g["cos"][g["train"]].astype(np.float32)
    at = np.einsum("nj,tnj->tn", w, fc[:, idx])
    y = np.log(fc / prior.channel_scales(at.reshape(n, 3, -1)).reshape(-1, 1).astype(np.float32)
               + np.float32(prior.EPS)) - mu.astype(np.float32)
    whole = y - (y @ comps.T.astype(np.float32)) @ comps.astype(np.float32)
    dof = max(y.shape[0] - comps.shape[0] - 1, 1)
    ref = np.einsum("tm,tm->m", whole, whole, dtype=np.float64) / dof
    assert ref.min() > 0.01  # a real residual, not round-off
    np.testing.assert_allclose(resvar, ref, rtol=1e-4)
    # the rows' residual at the samples and their coefficients (the prior's correlated misfit, methods.priorfit)
    np.testing.assert_allclose(at_samples, np.einsum("nj,tnj->tn", w, whole[:, idx]), rtol=1e-3, atol=1e-4)
    np.testing.assert_allclose(rows_coef, y @ comps.T.astype(np.float32), rtol=1e-3, atol=1e-3)
