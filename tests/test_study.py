"""The speed/accuracy study: grid, derived bench configs, Pareto fronts, recommendations, and a real run."""

import csv
import sys

import numpy as np
import pytest

from simulator import study
from simulator.study import Case

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib


def test_full_grid_is_the_product_of_the_issue_settings():
    g = study.grid()
    assert len(g) == 4 * 4 * 3 * 2 * 2 * 6
    assert "mirror" in study.MATERIALS  # the issue's mirror-like sample
    assert {c.step_deg for c in g} == {0.5, 1.0, 2.0, 5.0}
    assert {c.n_slices for c in g} == {1, 2, 4, 8}
    assert {c.repeats for c in g} == {1, 4, 16}
    assert {c.plan for c in g} == {"uniform", "adaptive"}
    assert {c.material for c in g} == set(study.MATERIALS)
    assert len(study.grid(quick=True, materials=["diffuse"])) == 4
    with pytest.raises(ValueError, match="unknown material"):
        study.grid(materials=["velvet"])


def test_case_config_sets_material_plan_noise_and_seed():
    base = tomllib.loads(open("configs/simulated.toml", encoding="utf-8").read())
    c = Case("sharp-ggx", 1.0, 4, 16, "adaptive", "high")
    cfg = study.case_config(base, c)
    assert cfg["material"] == study.MATERIALS["sharp-ggx"]
    assert cfg["plan"]["theta_i_deg"] == study.INCIDENCES[4]
    assert cfg["plan"]["repeats"] == 16 and cfg["detector"]["repeats"] == 16
    assert cfg["plan"]["adaptive"] == {"coarse_step_deg": 5.0, "min_step_deg": 1.0, "tolerance": 0.05}
    assert cfg["simulator"]["source_power"] == study.NOISE["high"]["source_power"]
    assert cfg["simulator"]["seed"] == c.seed and cfg["simulator"]["time_scale"] == 0.0
    assert base["material"]["name"] == "blue-plastic"  # the base is not modified
    assert Case("diffuse", 2.0, 1, 4, "uniform", "low").seed != Case("diffuse", 2.0, 1, 4, "uniform", "high").seed


def row(t, e, method="fit", material="m"):
    return {"material": material, "capture_time_s": t, "rel_rmse_cos": e, "status": "ok", "method": method,
            "step_deg": 1, "n_slices": 1, "repeats": 1, "plan": "uniform", "noise": "low"}


def test_pareto_front_and_recommendation():
    rows = [row(10, 0.5), row(20, 0.1), row(15, 0.6), row(40, 0.01), row(50, 0.02), row(30, 0.1)]
    front = study.pareto_front(rows)
    assert [(r["capture_time_s"], r["rel_rmse_cos"]) for r in front] == [(10, 0.5), (20, 0.1), (40, 0.01)]
    assert study.recommend(rows, 0.05)["m"]["capture_time_s"] == 40
    assert study.recommend(rows, 0.2)["m"]["capture_time_s"] == 20
    assert study.recommend(rows, 0.001)["m"] is None
    failed = {**row(1, 0.0), "status": "method failed"}
    assert study.recommend(rows + [failed], 0.05)["m"]["capture_time_s"] == 40


@pytest.fixture(scope="module")
def tiny_study(tmp_path_factory):
    d = tmp_path_factory.mktemp("study")
    cases = [Case("diffuse", 5.0, 1, 1, "uniform", "low")]
    rows = study.run_study(cases, "configs/simulated.toml", d / "work", d / "docs", "tiny", "test", workers=1,
                           progress=False)
    return d, rows


@pytest.mark.slow
def test_a_real_simulated_capture_is_reconstructed_by_every_method(tiny_study):
    d, rows = tiny_study
    assert [r["method"] for r in rows] == list(study.METHODS)
    fit = rows[0]
    assert fit["status"] == "ok", fit
    assert fit["rel_rmse_cos"] < 0.05  # a Lambertian is easy for the analytic fit
    assert fit["capture_time_s"] > 1.0  # bench time (the time model's, below), not the fast simulation's wall time
    assert fit["capture_wall_s"] > 0.0
    # plans are chosen by the time model's estimate, which is the simulated bench time of the capture
    # (less what auto-ranging cost, which depends on the sample and is its own column)
    assert 0.0 <= fit["auto_range_s"] < 0.5 * fit["bench_time_s"]
    assert fit["capture_time_s"] == pytest.approx(fit["bench_time_s"] - fit["auto_range_s"], rel=0.05)
    with open(d / "docs" / "tiny.csv", newline="") as fh:
        table = list(csv.DictReader(fh))
    assert len(table) == len(study.METHODS) and table[0]["material"] == "diffuse"
    md = (d / "docs" / "study.md").read_text()
    section = study.study_section(md, "tiny")
    assert section is not None and "### Recommendations" in section and "| budget 2% | budget 5% |" in section
    assert "| diffuse | " in section and "[tiny.csv](tiny.csv)" in section and "(tiny-pareto.png)" in section
    png = (d / "docs" / "tiny-pareto.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 5000


@pytest.mark.slow
def test_the_same_cases_run_on_a_dask_cluster(tmp_path):
    import distributed  # the test extra installs it; the feature is --scheduler ADDRESS
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True, dashboard_address=None) as lc:
        rows = study.run_study([Case("diffuse", 5.0, 1, 1, "uniform", "low")], "configs/simulated.toml",
                               tmp_path / "w", tmp_path / "o", "dask", "test", scheduler=lc.scheduler_address,
                               progress=False)
    assert rows[0]["status"] == "ok" and rows[0]["rel_rmse_cos"] < 0.05


def test_cli_rejects_unknown_materials_and_missing_config(capsys):
    from simulator.cli import main

    assert main(["study", "--materials", "velvet"]) == 2
    assert "unknown material" in capsys.readouterr().err
    assert main(["bench", "--config", "nowhere.toml"]) == 2  # the command's old name still runs it
    assert "no such file" in capsys.readouterr().err


@pytest.mark.slow
def test_a_case_is_recaptured_when_its_config_changed_and_resumed_when_not(tmp_path, monkeypatch, request):
    request.addfinalizer(study.truth_table.cache_clear)  # no truth of the patched material outlives this test
    case = Case("diffuse", 5.0, 1, 1, "uniform", "low")
    base = open("configs/simulated.toml", encoding="utf-8").read()
    first = study.run_case((case, base, str(tmp_path)))[0]
    slice_csv = tmp_path / case.name / "capture" / "slice.csv"
    stamp = slice_csv.stat().st_mtime_ns
    again = study.run_case((case, base, str(tmp_path)))[0]  # same config: the finished capture is reused
    record = slice_csv.parent / "capture.json"
    why = f"capture.json: {record.read_text()[-1500:] if record.exists() else '-'}"
    assert slice_csv.stat().st_mtime_ns == stamp, why  # a reused capture is not written again
    assert again["rel_rmse_cos"] == first["rel_rmse_cos"]
    # ... and keeps its times (the resumed run itself did nothing: its summary says 0 s)
    assert first["capture_time_s"] > 1.0 and first["bench_time_s"] > 1.0
    for key in ("capture_time_s", "bench_time_s", "auto_range_s"):
        assert again[key] == pytest.approx(first[key], rel=1e-6, abs=1e-9), key
    monkeypatch.setitem(study.MATERIALS, "diffuse", {"name": "diffuse", "lobes": [{"type": "lambert",
                                                                                    "albedo": 0.3}]})
    study.truth_table.cache_clear()  # the cached truth belongs to the old material
    changed = study.run_case((case, base, str(tmp_path)))[0]  # another material: captured again
    assert changed["status"] == "ok" and changed["rel_rmse_cos"] < 0.05
    from reconstruction.formats.slicefile import read_slice

    assert read_slice(slice_csv).values.mean() < 0.7 * 0.6 / np.pi  # the new, darker material's samples


@pytest.mark.slow
def test_a_material_dir_gives_neural_and_toml_materials_to_the_study(tmp_path):
    from tests.test_nbrdf_energy import write_nbrdf

    d = tmp_path / "mats"
    d.mkdir()
    write_nbrdf(d / "neural", seed=4)
    (d / "paint.toml").write_text('[material]\nname = "paint"\n[[material.lobes]]\ntype = "lambert"\nalbedo = 0.4\n')
    (d / "notes.toml").write_text('title = "not a material"\n')
    cat = study.materials_from_dir(d)
    assert sorted(cat) == ["neural", "paint"]
    assert cat["neural"]["lobes"][0] == {"type": "nbrdf", "path": str((d / "neural").resolve())}
    cases = study.grid(reduced=True, catalogue=cat)
    assert len(cases) == 2 * len(study.REDUCED_SETTINGS)
    with pytest.raises(ValueError, match="no neural BRDF"):
        study.materials_from_dir(tmp_path / "mats" / "..")  # no material at that level
    # a real simulated capture of the neural material, judged within 80 deg as well
    base = open("configs/simulated.toml", encoding="utf-8").read()
    case = Case("neural", 5.0, 1, 1, "uniform", "low")
    rows = study.run_case((case, base, str(tmp_path / "work"), cat["neural"]))
    assert [r["method"] for r in rows] == list(study.METHODS)
    assert all(r["status"] == "ok" for r in rows), rows
    assert all(0 <= r["rmse80"] < 10 for r in rows)


def test_cli_material_dir_errors_are_one_line(capsys, tmp_path):
    from simulator.cli import main

    assert main(["bench", "--material-dir", str(tmp_path / "none")]) == 2
    assert "--material-dir" in capsys.readouterr().err


def test_the_study_writes_to_out_by_default_and_estimates_its_duration():
    from simulator.cli import build_parser

    args = build_parser().parse_args(["study", "--quick"])
    assert args.out == "out/study"  # a user's run never rewrites the committed docs/
    quick = study.grid(quick=True)
    est1, est2 = study.estimate_seconds(quick, 1), study.estimate_seconds(quick, 2)
    assert est2 == pytest.approx(est1 / 2) and 60 < est2 < 1200
    fine = study.estimate_seconds([Case("diffuse", 0.5, 8, 16, "uniform", "low")], 1)
    coarse = study.estimate_seconds([Case("diffuse", 5.0, 1, 1, "uniform", "low")], 1)
    assert fine > coarse + 10  # thousands of samples cost more than a handful


def test_merge_keeps_an_earlier_runs_rows_for_the_materials_not_rerun(tmp_path, capsys):
    row = {"material": "diffuse", "step_deg": 5.0, "n_slices": 1, "repeats": 1, "plan": "uniform", "noise": "low",
           "method": "fit", "method_used": "fit", "status": "ok", "samples": 33, "capture_time_s": 7.0,
           "recon_time_s": 0.5, "rel_rmse_cos": 0.01, "log_rmse": 0.01, "sphere_rel_error": 0.01,
           "albedo_max_abs_error": 0.001}
    old = tmp_path / "old.csv"
    study.write_csv(old, [row, {**row, "material": "mirror", "rel_rmse_cos": 0.5}])
    kept = study.read_rows(old)
    assert "rmse80" not in kept[0]  # a column the earlier run left empty stays missing
    # a run of mirror keeps diffuse's earlier row and drops the earlier mirror row
    new = [{**row, "material": "mirror", "method": "auto", "rel_rmse_cos": 0.05}]
    merged, note = study.merge_rows(new, kept, {"mirror"}, "old.csv")
    assert [(r["material"], r["method"]) for r in merged] == [("mirror", "auto"), ("diffuse", "fit")]
    assert note.endswith("the rows of mirror are computed by this command.")
    assert study.merge_rows(new, kept, {"mirror", "diffuse"}, "old.csv") == (new, "")
    rows = study.run_study([], "configs/simulated.toml", tmp_path / "w", tmp_path / "out", "s", "test", workers=1,
                           progress=False, merge=kept, merge_source=str(old))
    assert len(rows) == 2  # nothing ran: every earlier row kept
    md = (tmp_path / "out" / "study.md").read_text()
    assert f"Rows of diffuse, mirror (2 rows, methods fit) are taken from {old} (--merge)." in md
    assert "| diffuse | 7.0 s: fit, step 5 deg, 1 slice(s), 1 repeat(s), uniform, low noise (1.00%) | the same |" in md
    assert [r["material"] for r in study.read_rows(tmp_path / "out" / "s.csv")] == ["diffuse", "mirror"]
    bad = tmp_path / "bad.csv"
    bad.write_text("a,b\n1,2\n")
    with pytest.raises(ValueError, match="not a study CSV"):
        study.read_rows(bad)
    from simulator.cli import main

    assert main(["bench", "--materials", "mirror", "--merge", str(bad)]) == 2
    assert "--merge" in capsys.readouterr().err


def test_the_committed_quick_study_has_the_shape_its_command_makes():
    """Issue 41: docs/study-quick.* held 20 captures of 5 materials where `gonio-sim study --quick` makes 24 of 6.
    The committed study must hold the materials and the captures the command it names would make (from the
    command's own configuration: simulator.study.grid; nothing is run)."""
    import csv
    import re
    from pathlib import Path

    from simulator.study import METHODS, grid

    docs = Path(__file__).resolve().parents[1] / "docs"
    md = study.study_section((docs / "study.md").read_text(encoding="utf-8"), "study-quick")
    command = re.search(r"Produced by `([^`]+)`", md).group(1)
    assert command.split()[:3] == ["gonio-sim", "study", "--quick"]
    materials = re.search(r"--materials (\S+)", command)
    cases = grid(True, materials.group(1).split(",") if materials else None)
    with open(docs / "study-quick.csv", newline="", encoding="utf-8") as fh:
        rows = list(csv.DictReader(fh))
    key = ("material", "step_deg", "n_slices", "repeats", "plan", "noise")
    captured = {tuple(r[k] for k in key) for r in rows}
    wanted = {(c.material, f"{c.step_deg:g}", str(c.n_slices), str(c.repeats), c.plan, c.noise) for c in cases}
    assert {r["material"] for r in rows} == {c.material for c in cases}
    assert captured == wanted
    assert len(rows) == len(cases) * len(METHODS)
    assert f"{len(rows)} rows ({len(cases)} captures)" in md


def test_a_study_rewrites_its_own_section_of_the_one_study_page_and_keeps_the_rest(tmp_path):
    """Issue 51: one study page; a run writes its own section (between markers) and keeps the page's other text and
    the other studies' sections; every row stays in the CSV, not on the page."""
    rows = [{**row(10, 0.5, material="diffuse"), "step_deg": 5}, row(20, 0.01, material="diffuse"),
            {**row(30, 0.2, "auto", "mirror"), "status": "method failed"}]
    page = tmp_path / study.STUDY_PAGE
    study.write_markdown(page, rows, "a", "gonio-sim study --quick")
    assert page.read_text().startswith("# Speed/accuracy study\n")  # a new page gets its introduction
    page.write_text(page.read_text().replace("# Speed/accuracy study", "# My study\n\nMy own words."))
    study.write_markdown(page, rows[:1], "b", "gonio-sim study --name b")
    study.write_markdown(page, rows, "a", "gonio-sim study --quick --materials diffuse")  # a again: replaced
    text = page.read_text()
    assert text.startswith("# My study\n\nMy own words.") and text.count("\n## a\n") == 1
    a, b = study.study_section(text, "a"), study.study_section(text, "b")
    assert text.index(a) < text.index(b)  # rewritten where it was
    assert "Produced by `gonio-sim study --quick --materials diffuse`." in a
    assert "3 rows (3 captures), 1 failed: [a.csv](a.csv)." in a
    assert "| diffuse | 20.0 s: fit, step 1 deg, 1 slice(s), 1 repeat(s), uniform, low noise (1.00%) | the same |" in a
    assert "| mirror | not reached (best inf%) |" in a  # its only row failed
    assert "0.50%" not in b and "50.00%" in b  # b has its own rows
    assert "| 20 |" not in text and "All results" not in text  # no row-by-row table


def test_the_committed_study_page_is_short_and_is_what_its_csvs_make():
    """Issue 51: docs/study.md was 4,273 lines, mostly a table that repeated docs/study.csv. Now one page under
    500 lines whose three sections are exactly what `gonio-sim study` writes from the committed CSVs (each
    section's command and --merge sentence read from the section itself), with each study's plot beside it."""
    import re
    from pathlib import Path

    docs = Path(__file__).resolve().parents[1] / "docs"
    text = (docs / "study.md").read_text(encoding="utf-8")
    assert len(text.splitlines()) < 500
    assert not (docs / "study-quick.md").exists() and not (docs / "study-real-materials.md").exists()
    for name in ("study", "study-quick", "study-real-materials"):
        section = study.study_section(text, name)
        assert section is not None, name
        command = re.search(r"Produced by `([^`]+)`", section).group(1)
        merged = re.search(r"^(Rows of .*\(--merge\).*)$", section, re.M)
        metric = "rmse80" if "--material-dir" in command else "rel_rmse_cos"
        rows = study.read_rows(docs / f"{name}.csv")
        want = study.section_lines(rows, name, command, metric, merged.group(1) if merged else "")
        assert section == "\n".join(want), name
        png = (docs / f"{name}-pareto.png").read_bytes()
        assert png[:8] == b"\x89PNG\r\n\x1a\n" and f"({name}-pareto.png)" in section
