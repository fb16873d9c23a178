"""gonio-reconstruct end to end, method dispatch (auto), and clear errors for bad input."""

import json
import subprocess
import sys

import numpy as np
import OpenEXR
import pytest

from reconstruction import cli, pipeline
from reconstruction.base import ReconstructionError
from reconstruction.core import merlgrid, merltable
from reconstruction.core.metrics import relative_rmse_cos
from reconstruction.core.models import Material
from reconstruction.core.slicedata import Slice
from reconstruction.formats import merl
from reconstruction.formats.slicefile import write_slice
from reconstruction.methods import Options, auto
from reconstruction.synthetic import synthetic_slice

BLUE_PLASTIC = Material.from_dict({"name": "blue-plastic", "lobes": [
    {"type": "lambert", "albedo": [0.05, 0.10, 0.40]},
    {"type": "ggx", "alpha": 0.15, "specular": [0.9, 0.9, 0.9], "f0": 0.04}]})
PHONG = Material.from_dict({"name": "phong-ish", "lobes": [  # no lobe of the fit can describe this well
    {"type": "oren_nayar", "albedo": 0.8, "sigma_deg": 40}, {"type": "phong", "exponent": 50, "specular": 0.3}]})


def slice_file(path, mat, incidences=(30.0,), step=2.0):
    s = synthetic_slice(mat, incidences, step_deg=step)
    n = len(s)
    write_slice(path, Slice(s.theta_i_deg, s.theta_o_deg, s.values, s.channels, 0.002 * np.abs(s.values) + 1e-6,
                            np.full(n, 4), 1.795e9 + np.arange(n), meta={"material": "test"}))
    return path


@pytest.mark.slow
def test_end_to_end_on_a_slice_file(tmp_path):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    out = tmp_path / "material.binary"
    r = subprocess.run([sys.executable, "-m", "reconstruction.cli", str(src), "--method", "auto", "--out", str(out),
                        "--preview", str(tmp_path / "material.exr"), "--report", str(tmp_path / "material.json")],
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    assert "Traceback" not in r.stderr
    assert out.stat().st_size == merl.FILE_SIZE == 34_992_012
    table = merl.read(out)
    assert np.all(np.isfinite(table[:, merlgrid.valid_mask()])) and np.nanmin(table) >= 0
    assert relative_rmse_cos(table, merltable.tabulate(BLUE_PLASTIC.eval)) < 0.02
    with OpenEXR.File(str(tmp_path / "material.exr")) as f:
        px = f.channels()["RGB"].pixels
    assert px.shape == (256, 256, 3) and px.dtype == np.float32 and px.max() > 0
    assert (tmp_path / "material.png").read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    rep = json.loads((tmp_path / "material.json").read_text())
    for key in ("method", "method_reason", "parameters", "residuals", "coverage", "checks"):
        assert key in rep
    assert rep["method"] == "fit" and rep["method_requested"] == "auto"
    assert "lowest held-out error" in rep["method_reason"]
    cv = rep["cross_validation"]
    assert cv["chosen"] == "fit" and "held-out contiguous blocks" in cv["scheme"]
    assert {c["method"] for c in cv["scores"]} == set(pipeline.METHODS) - {"auto", "prior"}  # prior: with --prior
    errs = [c["held_out_relative_rmse_cos"] for c in cv["scores"]]
    assert errs == sorted(errs) and cv["scores"][0]["method"] == "fit"
    assert rep["details"]["model"] == "lambert+ggx(F)"
    assert {c for c in rep["checks"]} >= {"non_negative", "albedo", "reciprocity"}
    assert rep["checks"]["all_pass"] is True
    assert len(rep["checks"]["albedo"]["albedo"]) == 18  # every incidence 0..85 deg
    assert rep["coverage"]["incidences"][0]["theta_i_deg"] == 30.0
    assert rep["residuals"]["relative_rmse_cos"] < 1e-3


def test_help_answers():
    r = subprocess.run([sys.executable, "-m", "reconstruction.cli", "--help"], capture_output=True, text=True,
                       timeout=60)
    assert r.returncode == 0
    for word in ("--method", "auto,fit,microfacet,revolve,bivariate", "--preview", "--report", "--supersample",
                 "--quantity", "--columns", "--illuminant", "--scene", "--allow-implausible"):
        assert word in r.stdout


@pytest.mark.slow
def test_generic_spectral_table_bivariate_supersampled(tmp_path):
    wl = np.arange(400, 701, 20)
    s = synthetic_slice(Material.from_dict({"name": "grey", "lobes": [
        {"type": "lambert", "albedo": 0.5}, {"type": "ggx", "alpha": 0.3, "specular": 0.2}]}), (20.0, 45.0),
        step_deg=5.0)
    ti, to, f = s.theta_i_deg, s.theta_o_deg, s.values
    lines = ["# other instrument export", "Incidence,Detector," + ",".join(f"{w}nm" for w in wl)]
    for a, b, v in zip(ti, to, np.pi * f[:, 0], strict=True):  # a reflectance factor, flat over wavelength
        lines.append(f"{a},{b}," + ",".join([repr(float(v))] * wl.size))
    src = tmp_path / "export.csv"
    src.write_text("\n".join(lines) + "\n")
    out = tmp_path / "m.binary"
    code = cli.main([str(src), "--method", "bivariate", "--out", str(out), "--columns",
                     "theta_i=Incidence,theta_o=Detector", "--quantity", "reflectance_factor",
                     "--supersample", "2,1,1", "--report", str(tmp_path / "m.json"), "--quiet"])
    assert code == 0
    rep = json.loads((tmp_path / "m.json").read_text())
    assert rep["method"] == "bivariate" and rep["colour"]["input_channels"] == "spectral"
    assert rep["table"]["values"] == "cell averages" and rep["table"]["supersample"] == [2, 1, 1]
    assert cli.build_parser().parse_args([str(src), "--out", "x.binary", "--supersample"]).supersample == "adaptive"
    assert cli.build_parser().parse_args([str(src), "--out", "x.binary", "--supersample", "4"]).supersample == (4, 4, 4)
    t = merl.read(out)
    v = merlgrid.valid_mask()
    assert np.all(np.isfinite(t[:, v]))
    # a flat (grey) spectrum gives a grey table, at the right level: the diffuse part near normal is 0.5/pi + ggx
    np.testing.assert_allclose(t[0, v], t[1, v], rtol=2e-3)
    np.testing.assert_allclose(t[2, v], t[1, v], rtol=2e-3)
    assert rep["residuals"]["relative_rmse_cos"] < 0.01


def run_main(capsys, *argv):
    code = cli.main([str(a) for a in argv])
    err = capsys.readouterr().err
    return code, err


BAD = [
    ("nan.csv", "theta_i,theta_o,value\n30,0,0.1\n30,10,nan\n30,20,0.3\n", ["--quantity", "brdf"],
     r"nan.csv:3, column value: value is 'nan'"),
    ("unknown.csv", "theta_i,theta_o,value,temp\n30,0,0.1,1\n", ["--quantity", "brdf"],
     "unknown.csv:1, column temp: unknown column"),
    ("noq.csv", "theta_i,theta_o,value\n30,0,0.1\n30,10,0.1\n30,20,0.1\n", [],
     "noq.csv: a generic table does not say what its values are"),
    ("zeros.csv", "theta_i,theta_o,value\n30,0,0\n30,10,0\n30,20,0\n30,50,0\n", ["--quantity", "brdf"],
     "zeros.csv: every value is zero"),
    ("one.csv", "theta_i,theta_o,value\n30,0,0.1\n", ["--quantity", "brdf"], "one.csv: 1 sample(s)"),
    ("dup.csv", "theta_i,theta_o,value\n30,0,0.1\n30,20,0.1\n40,10,0.1\n30,0,0.2\n", ["--quantity", "brdf"],
     "dup.csv:5, column theta_o: duplicate sample theta_i = 30.0, theta_o = 0.0 (also at line 2)"),
]


@pytest.mark.parametrize("name, text, extra, message", BAD, ids=[b[0] for b in BAD])
def test_bad_input_exits_2_with_one_line(tmp_path, capsys, name, text, extra, message):
    src = tmp_path / name
    src.write_text(text)
    out = tmp_path / "m.binary"
    code, err = run_main(capsys, src, "--out", out, "--quiet", *extra)
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert message in err
    assert not out.exists()  # never a table of NaN or zeros


def test_bad_options_exit_2(tmp_path, capsys):
    src = slice_file(tmp_path / "s.csv", BLUE_PLASTIC, step=10.0)
    code, err = run_main(capsys, src, "--out", tmp_path / "m.bin")
    assert code == 2 and "--out" in err and ".binary" in err
    code, err = run_main(capsys, src, "--out", tmp_path / "nodir" / "m.binary")
    assert code == 2 and "does not exist" in err
    code, err = run_main(capsys, tmp_path / "missing.csv", "--out", tmp_path / "m.binary")
    assert code == 2 and "missing.csv: no such file" in err
    code, err = run_main(capsys, src, "--out", tmp_path / "m.binary", "--lobes", "lambert,phong")
    assert code == 2 and "phong" in err
    code, err = run_main(capsys, src, "--out", tmp_path / "m.binary", "--scene", tmp_path / "none.toml")
    assert code == 2 and "none.toml: no such scene file" in err
    for bad in (["--method", "magic"], ["--supersample", "0,1,1"], ["--supersample", "x"]):
        with pytest.raises(SystemExit) as e:
            cli.main([str(src), "--out", str(tmp_path / "m.binary"), *bad])
        assert e.value.code == 2
    assert not (tmp_path / "m.binary").exists()


# --- dispatch --------------------------------------------------------------------------------------------


@pytest.mark.slow
def test_auto_chooses_by_held_out_prediction_on_a_material_outside_every_family():
    # rough Oren-Nayar diffuse + a Phong lobe: neither fit nor microfacet can describe it; three incidences
    s = synthetic_slice(PHONG, (10.0, 40.0, 70.0))
    rec, choice = pipeline.reconstruct(s, "auto")
    cv = choice["cross_validation"]
    assert cv["scheme"] == "leave-one-incidence-out" and cv["folds"] == 3
    best = min(cv["scores"], key=lambda c: c["held_out_relative_rmse_cos"])
    assert rec.method == choice["used"] == cv["chosen"] == best["method"]
    assert "lowest held-out error" in choice["reason"]
    # and the choice is good for the table, not only for the samples: within 25 % of the best method's error
    truth = merltable.tabulate(PHONG.eval)
    errs = {m: relative_rmse_cos(pipeline.tabulate(pipeline.reconstruct(s, m)[0]), truth)
            for m in pipeline.METHODS if m not in ("auto", "prior")}
    assert errs[rec.method] <= 1.25 * min(errs.values()), (rec.method, errs)
    assert errs[rec.method] < 0.5 * errs["fit"]  # the residual-based choice of old (fit) was far worse


def test_auto_never_uses_an_implausible_method(monkeypatch):
    # the best-predicting method reflects more light than it receives: auto takes the next
    from reconstruction import methods

    class Bright:
        method = "bivariate"
        channels = ["R", "G", "B"]

        def eval(self, wi, wo):
            return np.full((len(wi), 3), 0.5)  # albedo pi / 2

        def report(self):
            return {"method": "bivariate"}

    monkeypatch.setitem(methods.REGISTRY, "bivariate", methods.Method("bivariate", "bright", lambda s, o, p: Bright()))
    from reconstruction.methods.crossval import CVScore

    monkeypatch.setattr(auto, "cross_validate", lambda s, name, build, masks, inside=None: CVScore(
        name, 0.0 if name == "bivariate" else 0.1 + 0.01 * len(name), [], 0.0))
    rec, choice = pipeline.reconstruct(synthetic_slice(BLUE_PLASTIC, (30.0,)), "auto")
    assert rec.method != "bivariate"
    assert "bivariate" in choice["reason"] and "reflects more than it receives" in choice["reason"]


def test_options_reach_the_method_and_samples_arrive_sorted(monkeypatch):
    calls = []

    class Fake:
        method = "revolve"
        channels = ["value"]

        def eval(self, wi, wo):
            return np.full((len(wi), 1), 0.1)

        def report(self):
            return {"method": "revolve"}

    def fake_revolve(slices, **kw):
        calls.append((slices, kw))
        return Fake()

    monkeypatch.setattr("reconstruction.methods.revolve.reconstruct_revolve", fake_revolve)
    s = synthetic_slice(PHONG, (30.0,))
    order = np.random.default_rng(0).permutation(len(s))
    rec, choice = pipeline.reconstruct(s.take(order), "revolve", Options(fill="zero", revolve_axis="pca"))
    assert rec.method == "revolve" and choice["reason"] == "requested with --method revolve"
    (got, kw), = calls
    assert kw == {"axis": "pca", "fill": "zero", "reciprocal": True}
    assert np.all(np.diff(got.theta_o_deg) > 0)  # handed over sorted
    t = pipeline.tabulate(rec)
    assert np.allclose(t[:, merlgrid.valid_mask()], 0.1)


@pytest.mark.slow
def test_an_implausible_table_is_refused_with_exit_3_unless_allowed(tmp_path, capsys):
    # a flat f = 0.5 1/sr reflects pi / 2 of the light it receives: no honest table
    to = np.arange(-80.0, 81.0, 2.0)
    to = to[np.abs(to + 30.0) >= 4.0]
    src = tmp_path / "bright.csv"
    write_slice(src, Slice(np.full(to.size, 30.0), to, np.full((to.size, 1), 0.5), ["value"]))
    out, report = tmp_path / "m.binary", tmp_path / "m.json"
    code = cli.main([str(src), "--method", "bivariate", "--out", str(out), "--report", str(report), "--quiet"])
    err = capsys.readouterr().err
    assert code == 3
    assert "albedo" in err and "nothing written" in err and "--allow-implausible" in err and "Traceback" not in err
    assert not out.exists() and not report.exists()
    code = cli.main([str(src), "--method", "bivariate", "--out", str(out), "--report", str(report),
                     "--allow-implausible"])
    err = capsys.readouterr().err
    assert code == 0 and out.stat().st_size == merl.FILE_SIZE
    assert "IMPLAUSIBLE" in err and "--allow-implausible" in err
    rep = json.loads(report.read_text())
    assert rep["checks"]["all_pass"] is False and "albedo" in rep["implausible_table_written"]
    # fit and microfacet conserve energy by construction: the same samples give a plausible table
    for method in ("fit", "microfacet"):
        assert cli.main([str(src), "--method", method, "--out", str(out), "--quiet"]) == 0


def test_tabulate_refuses_negative_or_missing_cells():
    class Bad:
        method = "bad"
        channels = ["value"]

        def __init__(self, v):
            self.v = v

        def eval(self, wi, wo):
            return np.full((len(wi), 1), self.v)

        def report(self):
            return {}

    with pytest.raises(ReconstructionError, match="negative"):
        pipeline.tabulate(Bad(-0.1))
    with pytest.raises(ReconstructionError, match="no finite value"):
        pipeline.tabulate(Bad(np.nan))


def test_the_non_negative_check_reads_the_valid_cells_of_either_precision():
    """min, max and missing cells over the cells above the horizon, as a reader sees them, for float64 and float32
    tables (reduced in place, without table-sized copies)."""
    from reconstruction.core import merlgrid, merltable
    from reconstruction.core.checks import plausibility

    valid = merlgrid.valid_mask()[None]
    rng = np.random.default_rng(1)
    base = np.broadcast_to(rng.random((3, 90, 90, 1)) + 0.5, merltable.SHAPE).copy()
    base[:, ~merlgrid.valid_mask()] = -7.0  # below the horizon: never read
    bad = base.copy()
    bad[0, 5, 5, 5], bad[1, 6, 6, 6], bad[2, 0, 0, 0] = -0.25, np.nan, np.inf

    class Rec:
        method = "test"

        def eval(self, wi, wo):
            return np.full((len(wi), 1), 0.1)

    for table in (base, bad, bad.astype(np.float32)):
        t64 = table.astype(np.float64)
        read = np.where(valid, t64, np.nan)
        nn = plausibility(Rec(), table)["non_negative"]
        assert nn["missing_cells"] == int(np.sum(valid & ~np.isfinite(t64)))
        assert nn["min_1_per_sr"] == np.nanmin(read) and nn["max_1_per_sr"] == np.nanmax(read)
        assert nn["pass"] is (table is base)


@pytest.mark.slow
def test_every_method_passes_the_plausibility_checks(tmp_path):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC, incidences=(20.0, 40.0, 60.0))
    for method in ("fit", "microfacet", "bivariate", "revolve"):
        rep = cli.run(cli.build_parser().parse_args(
            [str(src), "--method", method, "--out", str(tmp_path / f"{method}.binary"), "--quiet"]))
        failed = [k for k in ("non_negative", "albedo", "reciprocity") if not rep["checks"][k]["pass"]]
        assert failed == [], (method, failed)


def test_fit_with_a_scene_reports_its_residuals_on_the_scene_samples(tmp_path):
    # glossy-product uses theta_i 15-45 deg: the 60 deg slice lies outside it; the scene's budget picks a
    # simpler model fitted to the samples inside, and its figures are judged on those samples
    s = synthetic_slice(BLUE_PLASTIC, (20.0, 40.0, 60.0), step_deg=2.0, noise=0.01, seed=3)
    n = len(s)
    src = tmp_path / "slice.csv"
    write_slice(src, Slice(s.theta_i_deg, s.theta_o_deg, s.values, s.channels, 0.01 * np.abs(s.values) + 1e-6,
                           np.full(n, 4), 1.795e9 + np.arange(n), meta={"material": "test"}))
    rep = cli.run(cli.build_parser().parse_args(
        [str(src), "--scene", "configs/scenes/glossy-product.toml", "--method", "fit",
         "--out", str(tmp_path / "m.binary"), "--quiet"]))
    assert rep["method"] == "fit", rep["method_reason"]
    res = rep["residuals"]
    assert res["samples_used"] < n  # the model was fitted to the scene's samples only
    assert res["relative_rmse_cos"] <= 0.03 < res["relative_rmse_cos_all_samples"]


@pytest.mark.parametrize("flag, value", [("--illuminant", "D99"), ("--axis", "diagonal"), ("--method", "magic")])
def test_bad_flag_values_are_rejected_before_any_work(tmp_path, capsys, flag, value):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    with pytest.raises(SystemExit) as e:
        cli.main([str(src), "--out", str(tmp_path / "m.binary"), flag, value])
    assert e.value.code == 2 and value in capsys.readouterr().err
    assert not (tmp_path / "m.binary").exists()


def test_the_fit_cannot_reflect_more_light_than_it_receives_on_a_hostile_capture():
    # a real simulated capture (study case back-scatter, 1 slice, 5 deg adaptive, 4 repeats, high noise) whose
    # best-fitting unconstrained lobes reached a directional albedo of ~39 at grazing incidence, outside the
    # measured slice: the energy-constrained fit stays <= 1 at every incidence, and so does its table
    from reconstruction.core.metrics import directional_albedo
    from reconstruction.formats.inputs import load_inputs

    s = load_inputs(["tests/data/implausible-fit-slice.csv"]).slice
    fit = pipeline.reconstruct(s, "fit")[0]
    alb = directional_albedo(fit.eval, np.radians(np.arange(0.0, 89.0, 5.0)), 64, 128)
    assert alb.max() <= 1.0 + 1e-3
    assert max(fit.report()["constraints"]["max_directional_albedo"]) <= 1.0 + 1e-9


# --- what a user sees: one-line messages, any letter case, compact reports --------------------------------


def test_a_missing_argument_is_one_line_pointing_at_help(capsys):
    with pytest.raises(SystemExit) as e:
        cli.main(["nothing.csv"])
    err = capsys.readouterr().err
    assert e.value.code == 2
    assert err.count("\n") == 1 and "--out" in err and "see gonio-reconstruct --help" in err and "usage:" not in err


def test_a_torn_last_line_is_one_plain_warning_line(tmp_path, capsys):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    src.write_text(src.read_text().rstrip("\n") + "\n30,5,0.1")  # an interrupted append
    assert cli.main([str(src), "--method", "bivariate", "--out", str(tmp_path / "m.binary"), "--quiet"]) == 0
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("gonio-reconstruct: warning: ") and "torn last line" in err[0]
    assert ".py" not in err[0] and "UserWarning" not in err[0]


def test_generic_column_names_match_in_any_letter_case(tmp_path):
    s = synthetic_slice(BLUE_PLASTIC, (30.0,))
    g = s.values.mean(axis=1)
    src = tmp_path / "other.csv"
    rows = zip(s.theta_i_deg, s.theta_o_deg, g, strict=True)
    src.write_text("THETA_I_DEG,Theta_O,Value,VALUE_STD\n" + "".join(f"{a},{b},{v},{0.01 * v}\n" for a, b, v in rows))
    rep = cli.run(cli.build_parser().parse_args([str(src), "--quantity", "brdf", "--method", "bivariate",
                                                 "--out", str(tmp_path / "m.binary"), "--quiet"]))
    assert rep["method"] == "bivariate" and rep["coverage"]["samples"] == len(s)


def test_the_report_keeps_arrays_on_one_line(tmp_path):
    src = slice_file(tmp_path / "slice.csv", BLUE_PLASTIC)
    report = tmp_path / "m.json"
    assert cli.main([str(src), "--method", "fit", "--out", str(tmp_path / "m.binary"), "--report", str(report),
                     "--quiet"]) == 0
    text = report.read_text()
    rep = json.loads(text)
    n = len(rep["residuals"]["samples"]["theta_o_deg"])
    assert n > 50 and text.count("\n") < 400  # the residual arrays are not one number per line
    lines = [ln.strip() for ln in text.splitlines() if ln.strip().startswith('"theta_o_deg": [')]
    assert any(ln[ln.index("["):ln.index("]")].count(",") == n - 1 for ln in lines)


def test_a_grey_table_says_how_to_get_colour(tmp_path, capsys):
    s = synthetic_slice(BLUE_PLASTIC, (30.0,))
    grey = Slice(s.theta_i_deg, s.theta_o_deg, s.values.mean(axis=1), ["value"])
    write_slice(tmp_path / "grey.csv", grey)
    assert cli.main([str(tmp_path / "grey.csv"), "--method", "bivariate", "--out", str(tmp_path / "m.binary")]) == 0
    err = capsys.readouterr().err
    assert "one band" in err and "spectrometer" in err
    assert cli.main([str(slice_file(tmp_path / "rgb.csv", BLUE_PLASTIC)), "--method", "bivariate",
                     "--out", str(tmp_path / "n.binary")]) == 0
    assert "one band" not in capsys.readouterr().err


def test_the_cli_keeps_freed_memory_for_reuse_on_glibc():
    """gonio-reconstruct asks glibc to keep freed memory (reconstruction.cliutil.keep_freed_memory): applied where
    the C library is glibc, a no-op elsewhere."""
    import platform

    from reconstruction.cliutil import keep_freed_memory

    glibc = sys.platform.startswith("linux") and platform.libc_ver()[0] == "glibc"
    assert keep_freed_memory() is glibc
