"""How sure a table is and which slice to measure next (reconstruction.assess), the prior's channel scales, and
auto's fall-back when the chosen method's table fails a check. Synthetic data only."""

import json
import subprocess
import sys

import numpy as np
import pytest

from reconstruction import pipeline
from reconstruction.assess import advice, uncertainty
from reconstruction.core.models import Material
from reconstruction.formats.slicefile import write_slice
from reconstruction.job import Job
from reconstruction.methods import auto, prior
from reconstruction.synthetic import synthetic_slice

PLASTIC = Material.from_dict({"name": "plastic", "lobes": [
    {"type": "lambert", "albedo": 0.2}, {"type": "ggx", "alpha": 0.12, "specular": 1.0, "f0": 0.04}]})


@pytest.fixture(scope="module")
def cache(tmp_path_factory):
    """A private cache folder, so the analytic prior is built here once and nothing else's cache is touched."""
    mp = pytest.MonkeyPatch()
    mp.setenv("XDG_CACHE_HOME", str(tmp_path_factory.mktemp("cache")))
    uncertainty.analytic_prior.cache_clear()
    yield
    uncertainty.analytic_prior.cache_clear()
    mp.undo()


@pytest.fixture(scope="module")
def one_slice(cache):
    s = synthetic_slice(PLASTIC, (20.0,)).sorted()
    rec, _ = pipeline.reconstruct(s, "bivariate")
    return s, rec, uncertainty.assess_table(rec, s)


def test_sigma_is_larger_where_the_table_is_extrapolated(one_slice):
    s, rec, (sigma, section, ref, sg, f_grid) = one_slice
    assert sigma.shape == (3, 90, 90, 180) and sigma.dtype == np.float32
    ms = section["median_sigma"]
    assert ms["extrapolated"] > 1.5 * ms["measured"], ms
    assert section["cells"]["measured"] > 0 and section["cells"]["extrapolated"] > section["cells"]["measured"]
    # cell by cell: the measured cells' sigma is below the extrapolated cells' in the same theta_d band
    classes = uncertainty.cell_classes(s)
    from reconstruction.core import merlgrid

    valid = merlgrid.valid_mask()
    meas = np.median(sigma[0][valid & (classes == 0)])
    grazing = np.median(sigma[0][:, 70:85][valid[:, 70:85] & (classes[:, 70:85] == 2)])
    assert grazing > 2 * meas, (grazing, meas)
    for k in ("expected_psnr_db", "expected_linear_image_error", "expected_cosl2"):
        assert np.isfinite(section[k])


def test_without_a_prior_sigma_is_the_ensembles_times_the_calibration(one_slice):
    """No prior: sigma = SIGMA_SCALE_ANALYTIC x sqrt(sigma_posterior^2 + d^2 / 4) (capped); with another prior than
    the built-in family, unscaled."""
    import dataclasses

    s, rec, (sigma, section, ref, sg, f_grid) = one_slice
    assert ref.info["prior"]["folder"] == uncertainty.ANALYTIC_NAME and uncertainty.SIGMA_SCALE_ANALYTIC > 1.0
    other = dataclasses.replace(ref, info={**ref.info, "prior": {**ref.info["prior"], "folder": "user folder"}})
    raw = uncertainty.sigma_grid(rec, other)
    below = raw < prior.SIGMA_LN_MAX / uncertainty.SIGMA_SCALE_ANALYTIC
    assert below.mean() > 0.5
    np.testing.assert_allclose(sg[below], uncertainty.SIGMA_SCALE_ANALYTIC * raw[below], rtol=1e-12)
    assert np.all(sg <= prior.SIGMA_LN_MAX)


def test_more_slices_lower_the_expected_error(one_slice):
    s, rec, (_, section, *_) = one_slice
    s3 = synthetic_slice(PLASTIC, (20.0, 45.0, 70.0)).sorted()
    rec3, _ = pipeline.reconstruct(s3, "bivariate")
    _, section3, *_ = uncertainty.assess_table(rec3, s3)
    assert section3["expected_cosl2"] < section["expected_cosl2"]
    assert section3["expected_psnr_db"] > section["expected_psnr_db"]
    assert section3["median_sigma"]["extrapolated"] < section["median_sigma"]["extrapolated"]


def test_the_advice_picks_an_incidence_that_reveals_the_grazing_peak(one_slice):
    # from one slice at 20 deg, a glossy dielectric's grazing Fresnel peak is a guess: the advice goes high
    s, rec, (_, section, ref, sg, f_grid) = one_slice
    a = advice.advise(s, ref, advice.BenchLimits(), current=section, sigma_now=sg, f_grid=f_grid)
    assert a["recommended_theta_i_deg"] >= 60.0, a["candidates"][:4]
    thetas = [c["theta_i_deg"] for c in a["candidates"]]
    assert 20.0 not in thetas and max(thetas) <= 80.0 and min(thetas) >= 0.0
    best, worst = a["candidates"][0], a["candidates"][-1]
    assert best["expected_psnr_db"] > worst["expected_psnr_db"]
    assert all(c["bench_time_s"] > 0 for c in a["candidates"])


def test_the_advice_follows_the_bench_limits_and_a_budget(one_slice, tmp_path):
    s, rec, (_, section, ref, sg, f_grid) = one_slice
    bench = tmp_path / "bench.toml"
    bench.write_text("[bench]\nblind_spot_half_width_deg = 6.0\n[axes.light]\nmin_deg = 10.0\nmax_deg = 50.0\n"
                     "[axes.detector]\nmin_deg = -80.0\nmax_deg = 80.0\n[motion]\nsettle_s = 0.5\n"
                     "velocity_deg_s = 20.0\n[detector]\nintegration_time_s = 0.1\nrepeats = 2\n", encoding="utf-8")
    lim = advice.bench_limits(bench)
    assert (lim.light_min_deg, lim.light_max_deg, lim.blind_spot_deg) == (10.0, 50.0, 6.0)
    assert lim.point_s == pytest.approx(0.5 + 0.2 + 0.1)
    a = advice.advise(s, ref, lim, budget_s=150.0, current=section, sigma_now=sg, f_grid=f_grid)
    thetas = [c["theta_i_deg"] for c in a["candidates"]]
    assert min(thetas) >= 10.0 and max(thetas) <= 50.0
    plan = a["plan"]
    assert plan["bench_time_s"] <= 150.0 and 1 <= len(plan["theta_i_deg"]) <= 2  # ~62 s a slice
    with pytest.raises(Exception, match="invalid TOML"):
        bad = tmp_path / "bad.toml"
        bad.write_text("[axes\n", encoding="utf-8")
        advice.bench_limits(bad)


def test_the_advice_says_when_every_reachable_incidence_is_measured(one_slice, tmp_path):
    # a hemispherical file, or slices at every step the bench reaches: a note, not a refusal of the whole run
    s, rec, (_, section, ref, sg, f_grid) = one_slice
    bench = tmp_path / "bench.toml"
    bench.write_text("[axes.light]\nmin_deg = 15.0\nmax_deg = 25.0\n", encoding="utf-8")
    lim = advice.bench_limits(bench)
    s2 = synthetic_slice(PLASTIC, (15.0, 20.0, 25.0)).sorted()
    a = advice.advise(s2, ref, lim, current=section, sigma_now=sg, f_grid=f_grid)
    assert a["recommended_theta_i_deg"] is None and a["candidates"] == []
    assert "measured already" in a["note"] and "15 to 25 deg" in a["note"]


def test_the_prior_leaves_out_samples_beyond_its_cells(cache):
    # samples at 87.5 deg read as the 81 deg cells' f cos cos put the misfit (and so sigma) at about 1 in ln; the
    # prior fits what its basis holds and says how many it left out
    near = synthetic_slice(PLASTIC, (20.0, 45.0)).sorted()
    grazing = synthetic_slice(PLASTIC, (20.0, 45.0, 87.5)).sorted()
    r_near = prior.reconstruct_prior(near, uncertainty.analytic_prior())
    r_all = prior.reconstruct_prior(grazing, uncertainty.analytic_prior())
    n_beyond = int(np.sum((grazing.theta_i_deg > 81.0) | (np.abs(grazing.theta_o_deg) > 81.0)))
    assert n_beyond > 0
    assert any(f"{n_beyond} samples beyond 81 deg" in n for n in r_all.info["notes"]), r_all.info["notes"]
    assert r_all.posterior["misfit"] < 2.0 * r_near.posterior["misfit"] + 0.02, (r_all.posterior["misfit"],
                                                                                r_near.posterior["misfit"])
    with pytest.raises(Exception, match="beyond 81 deg"):
        prior.reconstruct_prior(synthetic_slice(PLASTIC, (85.0,)).sorted(), uncertainty.analytic_prior())


def test_the_command_writes_the_sigma_array_and_the_report_sections(tmp_path, cache):
    s = synthetic_slice(PLASTIC, (30.0,))
    path = tmp_path / "s.csv"
    write_slice(path, s)
    r = subprocess.run([sys.executable, "-m", "reconstruction.cli", str(path), "--method", "bivariate",
                        "--uncertainty", str(tmp_path / "sigma.npy"), "--advise", "--report", str(tmp_path / "r.json")],
                       capture_output=True, text=True, timeout=600)
    assert r.returncode == 0, r.stderr
    sig = np.load(tmp_path / "sigma.npy")
    assert sig.shape == (3, 90, 90, 180) and sig.dtype == np.float32 and np.all(np.isfinite(sig))
    rep = json.loads((tmp_path / "r.json").read_text())
    assert set(rep["uncertainty"]["median_sigma"]) == {"measured", "interpolated", "extrapolated"}
    adv = rep["advice"]
    # the best expected candidate, or (the model cannot separate them) the tied one nearest PREFERRED_DEG
    pick, tied = advice.recommend({c["theta_i_deg"]: c["expected_psnr_db"] for c in adv["candidates"]})
    assert adv["recommended_theta_i_deg"] == pick and adv["candidates"][0]["theta_i_deg"] in tied
    assert ("tie" in adv) == (len(tied) > 1)
    assert set(adv["candidates"][0]) >= {"theta_i_deg", "expected_psnr_db", "expected_cosl2", "bench_time_s"}
    assert "advice: measure theta_i" in r.stderr and "uncertainty: median sigma" in r.stderr
    # --budget-s without --advise, a sigma file with another suffix: exit 2, one line
    for extra in (["--budget-s", "10"], ["--uncertainty", str(tmp_path / "x.txt")]):
        r = subprocess.run([sys.executable, "-m", "reconstruction.cli", str(path), "--out", str(tmp_path / "m.binary"),
                            *extra], capture_output=True, text=True, timeout=120)
        assert r.returncode == 2 and len(r.stderr.strip().splitlines()) == 1, r.stderr


def test_a_dark_channel_does_not_blow_up_the_prior(tmp_path, monkeypatch):
    # a saturated red: its blue reflects almost nothing; with the channel's own median as its scale the mapped
    # vector of that channel became a bright material's (1e8 times too bright on real car paints)
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    prior._load_cached.cache_clear()
    folder = tmp_path / "prior"
    folder.mkdir()
    for k, (al, dark) in enumerate([(a, d) for a in (0.08, 0.15, 0.3, 0.5) for d in (1e-4, 0.3)]):
        (folder / f"m{k}.toml").write_text(
            f'[material]\nname = "m{k}"\n[[material.lobes]]\ntype = "lambert"\nalbedo = [0.6, 0.2, {dark}]\n'
            f'[[material.lobes]]\ntype = "ggx"\nalpha = {al}\nspecular = [0.9, 0.3, {dark}]\nf0 = 0.04\n',
            encoding="utf-8")
    red = Material.from_dict({"name": "red", "lobes": [{"type": "lambert", "albedo": [0.55, 0.15, 2e-4]},
                                                      {"type": "ggx", "alpha": 0.2, "specular": [0.9, 0.3, 2e-4],
                                                       "f0": 0.04}]})
    rec = prior.reconstruct_prior(synthetic_slice(red, (40.0,)), folder)
    from reconstruction.core.geometry import inplane_to_dirs

    wi, wo = inplane_to_dirs(np.radians(np.full(30, 60.0)), np.radians(np.linspace(-75, 75, 30)))
    got, want = rec.eval(wi, wo), red.eval(wi, wo)
    assert np.max(got[:, 2]) < 0.05 * np.max(want[:, 0]), (got[:, 2].max(), want[:, 0].max())
    prior._load_cached.cache_clear()


def test_auto_falls_back_when_the_chosen_table_fails_a_check(monkeypatch, tmp_path):
    # the best-predicting method's BRDF passes auto's albedo screen but its written table does not (rows with a
    # directional albedo above 1): the pipeline writes the next method's table instead of refusing (exit 3)
    from reconstruction import methods
    from reconstruction.methods.crossval import CVScore

    real = methods.REGISTRY["bivariate"]

    def build(s, o, p):
        rec = real.build(s, o, p)
        table = rec.table if hasattr(rec, "table") else None

        class Broken:
            method, channels = "bivariate", rec.channels

            def eval(self, wi, wo):
                return rec.eval(wi, wo)

            def table(self):
                t = np.array(table() if table else pipeline.tabulate(rec), copy=True)
                t[:, :30] *= 40.0  # rows the BRDF does not have: the table reflects more than it receives
                return t

            def report(self):
                return rec.report()

        return Broken()

    monkeypatch.setitem(methods.REGISTRY, "bivariate", methods.Method("bivariate", "broken", build))
    monkeypatch.setattr(auto, "cross_validate", lambda s, name, build, masks, inside=None: CVScore(
        name, 0.001 if name == "bivariate" else 0.1 + 0.01 * len(name), [], 0.0))
    s = synthetic_slice(PLASTIC, (20.0, 40.0, 60.0))
    path = tmp_path / "s.csv"
    write_slice(path, s)
    from reconstruction.report import html as htmlreport

    sent = []
    real_draw = htmlreport.draw_sample_figures
    monkeypatch.setattr(htmlreport, "draw_sample_figures",
                        lambda d, w, r, *a, **k: (sent.append(r.method), real_draw(d, w, r, *a, **k))[1])
    rep = pipeline.run(Job(inputs=(str(path),), out=str(tmp_path / "m.binary"), method="auto",
                                    html=str(tmp_path / "m.html")))
    assert rep["checks"]["all_pass"] and rep["method"] != "bivariate"
    assert rep["cross_validation"]["fell_back_from"] == "bivariate"
    assert "written instead" in rep["method_reason"]
    assert (tmp_path / "m.binary").is_file()
    # the page's figures were sent for bivariate as the run went on, then again for the method written
    assert sent == ["bivariate", rep["method"]]
    page = (tmp_path / "m.html").read_text(encoding="utf-8")
    assert f"<th>method used</th><td>{rep['method']}</td>" in page and page.count("data:image/png") == 12


def test_the_conservative_bound_lowers_only_unmeasured_cells(one_slice):
    """A table far too bright off the measured slice (a grazing lobe the slice at 20 deg never saw) is brought
    under the reference's median x e^sigma where no sample rests; measured cells stay the method's; the bounded
    BRDF evaluates as its table at bin centres, stays reciprocal and only loses energy."""
    from reconstruction.assess import guard
    from reconstruction.core import merlgrid, merltable

    s, rec, (_, _, ref, _, _) = one_slice
    bright = Material.from_dict({"name": "bright", "lobes": [
        {"type": "lambert", "albedo": 0.2}, {"type": "ggx", "alpha": 0.12, "specular": 1.0, "f0": 0.9}]})

    class Wrong:  # the measured slice's values where measured, a metal's grazing rise elsewhere
        method = "wrong"
        eval = staticmethod(bright.eval)

        def report(self):
            return {"method": "wrong"}

    table = merltable.tabulate(bright.eval)
    bounded, out, info = guard.conservative(Wrong(), table, s, ref)
    free = uncertainty.cell_classes(s) > 0
    valid = merlgrid.valid_mask()
    assert info["applied"] and 1000 < info["cells_lowered"] <= info["cells"] and 0.0 < info["energy_removed"] < 1.0
    assert info["cells_lowered"] == int(np.sum(merlgrid.valid_mask() & np.any(out < table, axis=0)))
    np.testing.assert_array_equal(out[:, valid & ~free], table[:, valid & ~free])  # measured: untouched
    bound = guard.upper_bound_table(ref)
    assert np.all(out[:, valid & free] <= np.maximum(table, bound)[:, valid & free])
    assert np.all(out[:, valid] <= table[:, valid])
    lowered = valid & free & (out[0] < table[0])
    assert np.all(np.isclose(out[0][lowered], bound[0][lowered]))
    # eval at bin centres of lowered cells = the table there; reciprocal
    ih, idd, ip = (a[:50] for a in np.nonzero(lowered))
    wi, wo = merlgrid.cell_to_dirs(ih, idd, ip)
    np.testing.assert_allclose(bounded.eval(wi, wo)[:, 0], out[0][ih, idd, ip], rtol=1e-6)
    np.testing.assert_allclose(bounded.eval(wi, wo), bounded.eval(wo, wi), rtol=1e-9)
    assert bounded.method == "wrong" and bounded.report() == {"method": "wrong"}
    # a bound that would take less than min_energy of the light is not applied: the table as the method wrote it
    _, kept, why = guard.conservative(Wrong(), table, s, ref, min_energy=info["energy_removed"] + 0.01)
    assert not why["applied"] and why["cells_lowered"] == 0 and why["would_remove"] == info["energy_removed"]
    assert kept is table and "less than" in why["why"]
    _, again, _ = guard.conservative(Wrong(), table, s, ref, min_energy=info["energy_removed"] - 0.01)
    np.testing.assert_array_equal(again, out)
    # a reference whose band does not hold the samples themselves does not bound (a mirror against lambert + GGX)
    assert guard.samples_above(guard.upper_bound_table(ref, 3.0), s) == 0.0  # the plastic's family holds it
    low = 0.3 * guard.upper_bound_table(ref, 0.0)  # a band far under what was measured: 70 % of its light above
    assert 0.6 < guard.samples_above(low, s) < 0.8
    # points anywhere are judged at their own directions, not at the in-plane pair their polar angles name
    from reconstruction.core import merlgrid, merltable
    from reconstruction.core.samples import DirectionalSlice

    band = np.zeros(merltable.SHAPE)
    band[:, :, 15:, :] = 1.0  # a bound of 1 from theta_d = 15 deg on, 0 below
    v = np.full((1, 3), 0.5)
    # polar angles 28.6 / -28.6 deg: in the plane that is the retro direction (theta_d 0, under a bound of 0); the
    # point's own directions lie out of the plane at theta_d 19.8 deg, under a bound of 1
    pts = DirectionalSlice(np.full(1, 28.6), np.full(1, -28.6), v, ["R", "G", "B"], np.zeros_like(v),
                           wi=[[-np.sin(0.5), 0.0, np.cos(0.5)]], wo=[[0.0, np.sin(0.5), np.cos(0.5)]])
    assert guard.samples_above(band, pts) == 0.0
    assert guard.samples_above(1.0 - band, pts) == pytest.approx(1.0)
    _, kept, why = guard.conservative(Wrong(), table, s, ref, k=-4.0, max_above=0.02)
    assert kept is table and not why["applied"] and why["samples_above"] > 0.1 and "does not describe" in why["why"]


def test_auto_reports_its_bound_with_a_prior_and_without(tmp_path, cache):
    folder = tmp_path / "prior"
    folder.mkdir()
    for k in range(4):
        (folder / f"m{k}.toml").write_text(
            f'[material]\nname = "m{k}"\n[[material.lobes]]\ntype = "lambert"\nalbedo = {0.1 + 0.1 * k}\n'
            f'[[material.lobes]]\ntype = "ggx"\nalpha = {0.08 + 0.05 * k}\nspecular = 1.0\nf0 = 0.04\n',
            encoding="utf-8")
    s = synthetic_slice(PLASTIC, (30.0,)).sorted()
    src = tmp_path / "s.csv"
    write_slice(src, s.__class__(s.theta_i_deg, s.theta_o_deg, s.values, s.channels, 0.002 * s.values + 1e-6,
                                 np.full(len(s), 4), 1.795e9 + np.arange(len(s)), meta={"material": "t"}))
    for extra, applied in ((["--prior", str(folder)], None), ([], False)):
        rep = tmp_path / "r.json"
        r = subprocess.run([sys.executable, "-m", "reconstruction.cli", str(src), "--method", "auto",
                            "--out", str(tmp_path / "m.binary"), "--report", str(rep), *extra],
                           capture_output=True, text=True)
        assert r.returncode == 0, r.stderr
        c = json.loads(rep.read_text())["conservative"]
        if applied is None:
            assert "cells_lowered" in c and "reference posterior" in c["rule"] and str(folder) in c["reference"]
            assert ("conservative: " in r.stderr) == c["applied"], r.stderr
        else:  # the built-in analytic family bounds it, looser, and only a bold extrapolation
            from reconstruction.assess import guard

            assert c["reference"] == "built-in analytic family" and c["k"] == guard.GUARD_SIGMAS_ANALYTIC
            assert ("conservative: " in r.stderr) == c["applied"], r.stderr
            if not c["applied"]:
                assert 0.0 < c["would_remove"] < guard.ANALYTIC_MIN_ENERGY and "less than" in c["why"]


def test_candidates_the_model_cannot_separate_go_to_the_preferred_incidence():
    # within TIE_DB of the best: equivalent, the one nearest PREFERRED_DEG wins; a clear winner stays the winner
    t = advice.TIE_DB / 2
    pick, tied = advice.recommend({60.0: 30.0, 65.0: 30.0 + t, 75.0: 30.0, 20.0: 25.0})
    assert pick == advice.PREFERRED_DEG and tied == [60.0, 65.0, 75.0]
    pick, tied = advice.recommend({20.0: 30.0 + 3 * advice.TIE_DB, 75.0: 30.0, 70.0: 30.0})
    assert pick == 20.0 and tied == [20.0]


def _scene(text):
    from reconstruction.core.scene import scene_from_dict

    try:
        import tomllib
    except ModuleNotFoundError:  # pragma: no cover
        import tomli as tomllib
    return scene_from_dict(tomllib.loads(text), "test.toml")


FRONT = "[scene]\nname = 'front'\n[scene.view]\ngeometry = 'plane'\ncamera_deg = [5.0]\nlights_deg = [[8.0, 180.0]]\n"
GRAZING = ("[scene]\nname = 'grazing'\n[scene.view]\ngeometry = 'plane'\ncamera_deg = [72.0]\n"
           "lights_deg = [[75.0, 180.0]]\n")


def test_a_scenes_own_images_weigh_its_expected_errors_and_its_advice(one_slice):
    # the same table and sigma, two scenes: a plane lit and seen near the normal, and one at grazing angles, where
    # one slice at 20 deg leaves the Fresnel rise a guess. Each scene's expected errors are of its own pairs,
    # and its advice measures where its light comes from
    s, rec, (_, section, ref, sg, f_grid) = one_slice
    front, grazing = _scene(FRONT), _scene(GRAZING)
    ef = uncertainty.scene_section(front, f_grid, sg)
    eg = uncertainty.scene_section(grazing, f_grid, sg)
    assert ef["pairs"] == eg["pairs"] == 1 and "plane" in ef["weighs"]
    assert eg["expected_scene_linear_error"] > 2 * ef["expected_scene_linear_error"], (ef, eg)
    assert eg["expected_scene_psnr_db"] < ef["expected_scene_psnr_db"]
    af = advice.advise(s, ref, advice.BenchLimits(), current=section, sigma_now=sg, f_grid=f_grid, scene=front)
    ag = advice.advise(s, ref, advice.BenchLimits(), current=section, sigma_now=sg, f_grid=f_grid, scene=grazing)
    assert af["recommended_theta_i_deg"] <= 30.0, af["candidates"][:4]
    assert ag["recommended_theta_i_deg"] >= 65.0, ag["candidates"][:4]
    for a, sc in ((af, front), (ag, grazing)):
        assert sc.name in a["ranked_by"]
        psnr = [c["expected_scene_psnr_db"] for c in a["candidates"]]
        assert psnr == sorted(psnr, reverse=True)  # ranked by the scene's own images
    # with a budget, the plan is judged in the scene too: its expected PSNR is the scene's
    ab = advice.advise(s, ref, advice.BenchLimits(), budget_s=25.0, sigma_now=sg, f_grid=f_grid, scene=grazing,
                       current={"expected_psnr_db": section["expected_psnr_db"],
                                "expected_scene_psnr_db": eg["expected_scene_psnr_db"]})
    assert ab["plan"]["theta_i_deg"] and ab["plan"]["expected_psnr_db"] > eg["expected_scene_psnr_db"]


def test_a_sphere_scene_sees_every_pair_its_lights_make():
    # a sphere seen from +z lit from the camera: every pixel's light comes back along its view (wi = wo); a light
    # 90 deg off the camera lights half the sphere
    from reconstruction.core.scene import scene_pairs

    back = scene_pairs(_scene("[scene]\n[scene.view]\nlights_deg = [[0.0, 0.0]]\n"))
    lit = back.weight > 0
    assert back.kind == "sphere" and lit.all()
    np.testing.assert_allclose(back.wi[lit], back.wo[lit], atol=1e-6)
    side = scene_pairs(_scene("[scene]\n[scene.view]\nlights_deg = [[90.0, 0.0]]\n"))
    assert 0.4 < np.mean(side.weight > 0) < 0.6
    assert np.all((side.wi[..., 2] >= 0) & (side.wo[..., 2] > 0))
    # the brightest mirror pair of a sphere lit 90 deg off the camera is where the normal halves them
    half = np.cos(np.radians(45.0))
    dot = np.einsum("plk,plk->pl", side.wi, side.wo * np.array([-1.0, -1.0, 1.0]))  # wi . mirror(wo)
    k = np.argmax(np.where(side.weight > 0, dot, -2.0)[:, 0])
    assert dot[k, 0] > 0.995 and abs(side.wi[k, 0, 2] - half) < 0.05
    # a plane's light on the mirror side (azimuth 180) at the camera's polar angle is the mirror pair
    plane = scene_pairs(_scene(GRAZING.replace("75.0", "72.0")))
    np.testing.assert_allclose(plane.wi[0, 0], plane.wo[0, 0] * np.array([-1.0, -1.0, 1.0]), atol=1e-12)
    ranges = scene_pairs(_scene("[scene]\ntheta_i_deg = [10.0, 30.0]\ntheta_o_deg = [0.0, 20.0]\n"))
    t = ranges.theta_i_deg
    assert ranges.kind == "ranges" and t.min() >= 10.0 - 1e-9 and t.max() <= 30.0 + 1e-9


def test_the_advice_uses_the_bench_the_slice_file_records_and_never_advises_past_the_footprint(cache, tmp_path):
    """Issue 41: --advise assumed 0-80 deg and default timings whatever the capture's bench, and recommended 80 deg
    on the demo, past where its beam overfills the sample (75.5 deg), without a word. The bench recorded in the
    slice file's metadata is used; incidences beyond the footprint limit are excluded, and the advice says why."""
    from reconstruction.core.slicedata import Slice

    s = synthetic_slice(PLASTIC, (20.0,))
    meta = {"quantity": "brdf", "bench_name": "narrow bench",
            "config_settings": {"[axes.light].min_deg": 0.0, "[axes.light].max_deg": 70.0,
                                "[axes.detector].min_deg": -80.0, "[axes.detector].max_deg": 80.0,
                                "[motion].velocity_deg_s": 20.0, "[bench].blind_spot_half_width_deg": 5.0},
            "config_fingerprint": {"[motion].settle_s": 0.5, "[detector].integration_time_s": 0.1,
                                   "[plan].repeats": 2.0},
            "instrument": {"beam_diameter_mm": 10.0, "sample_diameter_mm": 20.0}}  # overfills beyond 60 deg
    lim = advice.capture_limits(meta, "s.csv")
    assert (lim.light_max_deg, lim.blind_spot_deg) == (70.0, 5.0)
    assert lim.point_s == pytest.approx(0.5 + 0.2 + 0.1) and lim.overfills_beyond_deg == pytest.approx(60.0)
    assert "narrow bench" in lim.source and advice.capture_limits({"quantity": "brdf"}, "t.csv") is None
    p = tmp_path / "s.csv"
    write_slice(p, Slice(s.theta_i_deg, s.theta_o_deg, s.values, list(s.channels), s.std, meta=meta))
    rep = pipeline.run(Job(inputs=(str(p),), out="", method="bivariate", advise=True,
                                    report=str(tmp_path / "r.json")))
    a = rep["advice"]
    thetas = [c["theta_i_deg"] for c in a["candidates"]]
    assert max(thetas) == 60.0 and a["recommended_theta_i_deg"] <= 60.0
    assert [e["theta_i_deg"] for e in a["excluded"]] == [65.0, 70.0]  # reachable, but the beam overfills
    assert "overfills the sample beyond 60.0 deg (a 10 mm beam on a 20 mm sample)" in a["excluded"][0]["why"]
    assert a["bench"].startswith(f"the bench recorded in {p}")
    assert a["candidates"][0]["bench_time_s"] == pytest.approx(round(len(advice.candidate_slice(
        a["candidates"][0]["theta_i_deg"], lim, ["value"])) * 0.8, 1))
