"""benchmarks/bench_real_materials.py on synthetic neural BRDFs (the real data are never needed by the tests)."""

import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import pytest

SHAPES = {"fc1": (6, 21), "b1": (21,), "fc2": (21, 21), "b2": (21,), "fc3": (21, 3), "b3": (3,)}


@pytest.fixture(scope="module")
def bench():
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_real_materials.py"
    spec = importlib.util.spec_from_file_location("bench_real_materials", path)
    mod = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = mod  # its worker function is pickled by name for the process pool
    spec.loader.exec_module(mod)
    yield mod
    sys.modules.pop(spec.name, None)


def test_cases_are_parsed(bench):
    assert bench.incidences_of("1") == (40.0,)
    assert bench.incidences_of("2") == (40.0, 70.0)
    assert bench.incidences_of("3") == (20.0, 40.0, 60.0)
    assert bench.incidences_of("20/50/75") == (20.0, 50.0, 75.0)
    assert bench.incidences_of("70") == (70.0,)
    assert bench._label("40/70") == "2 slice(s) at 40/70 deg"
    for bad, why in (("x", "expected 1, 2, 3 or incidences"), ("20/95", "0..80"), ("20//50", "expected")):
        with pytest.raises(ValueError, match=why):
            bench.incidences_of(bad)


def test_databases_and_the_contact_sheets_spread(bench):
    assert bench.database_of("/d/nbrdf-merl", "chrome") == "MERL"
    assert bench.database_of("/d/nbrdf-extra", "merl-teflon") == "MERL"
    assert bench.database_of("/d/nbrdf-extra", "rgl-satin_blue_rgb") == "RGL"
    assert bench.database_of("/d/nbrdf-extra", "nielsen-cardboard") == "Nielsen"
    by = {"MERL": [f"m{k:02d}" for k in range(88)], "RGL": [f"r{k:02d}" for k in range(47)], "Nielsen": ["n0", "n1"]}
    pick = bench.sheet_materials(by, 16)
    assert len(pick) >= 12 and len(set(pick)) == len(pick)
    assert {p[0] for p in pick} == {"m", "r", "n"}  # every database on the sheet
    assert "m00" in pick and "m87" in pick  # spread over the names


def write_nbrdf(prefix: Path, seed: int) -> None:
    """A small positive network (f about 0.05 to 0.3 /sr: albedo below 1), shaped by theta_h and theta_d."""
    rng = np.random.default_rng(seed)
    w = {"fc1": rng.normal(0, 1.0, (6, 21)), "b1": np.full(21, 0.1), "fc2": rng.normal(0, 0.4, (21, 21)),
         "b2": np.full(21, 0.1), "fc3": rng.uniform(0, 0.015, (21, 3)), "b3": np.full(3, 0.01)}
    for k, a in w.items():
        assert a.shape == SHAPES[k]
        np.save(f"{prefix}_{k}.npy", a)


@pytest.mark.slow
def test_benchmark_runs_every_case_on_a_data_folder(bench, tmp_path, capsys):
    data = tmp_path / "realdata"
    (data / "nbrdf-merl").mkdir(parents=True)
    (data / "nbrdf-extra").mkdir(parents=True)
    write_nbrdf(data / "nbrdf-merl" / "synthetic-a", 0)
    write_nbrdf(data / "nbrdf-extra" / "rgl-synthetic", 1)
    out = tmp_path / "records.jsonl"
    args = ["--data", str(data), "--methods", "bivariate,constant", "--workers", "1", "--cache", "", "--prior", "",
            "--jsonl", str(out), "--size", "16"]
    assert bench.main(args + ["--slices", "1,30/60"]) == 0
    lines = [json.loads(line) for line in out.read_text().splitlines()]
    recs = [r for r in lines if r.get("kind") != "floor"]
    floors = [r for r in lines if r.get("kind") == "floor"]
    assert sorted(f["material"] for f in floors) == ["rgl-synthetic", "synthetic-a"]
    assert {f["database"] for f in floors} == {"MERL", "RGL"}
    assert all(f["psnr_db"] > 30 and f["linear"] < 0.05 for f in floors)  # the table is close to its network
    assert len(recs) == 2 * 2 * 2
    for r in recs:
        for k in ("psnr_db", "psnr_key_db", "psnr_rim_db", "linear", "cosl2", "log", "rmse80", "grazing",
                  "linear_but_brightest", "linear_key_but_brightest", "linear_rim_but_brightest"):
            assert np.isfinite(r[k]), (k, r)
        assert r["linear_but_brightest"] == pytest.approx(
            (r["linear_key_but_brightest"] + r["linear_rim_but_brightest"]) / 2)
    by = {(r["material"], r["slices"], r["method"]): r for r in recs}
    for m in ("synthetic-a", "rgl-synthetic"):  # two slices see more of each material than one
        assert by[(m, "30/60", "bivariate")]["rmse80"] < by[(m, "1", "bivariate")]["rmse80"]
    printed = capsys.readouterr().out
    assert "floor (the truth's own MERL table" in printed and "    RGL " in printed
    assert bench.main(["--from-jsonl", str(out), "--methods", "bivariate,constant"]) == 0
    assert printed.split("1 slice(s) at 40 deg:")[1].split("2 materials")[0] in capsys.readouterr().out
    assert bench.main(args + ["--slices", "1,95"]) == 2
    assert "--slices" in capsys.readouterr().err
    assert bench.main(args + ["--quick", "--methods", "prior"]) == 2  # prior without a prior
    assert "need a prior" in capsys.readouterr().err


def _rec(material, method, psnr, lin, db="MERL", mode="1"):
    return {"material": material, "database": db, "slices": mode, "method": method, "psnr_db": psnr,
            "linear": lin, "psnr_key_db": psnr, "psnr_rim_db": psnr, "linear_key": lin, "linear_rim": lin,
            "cosl2": lin, "log": 0.1, "rmse80": lin, "grazing": 0.5, "plausible": True, "seconds": 0.1}


def test_the_summary_gives_medians_worst_cases_and_databases(bench):
    records = [_rec("a", "auto", 30.0, 0.10), _rec("b", "auto", 40.0, 0.60), _rec("c", "auto", 35.0, 0.20, "RGL"),
               _rec("a", "constant", 20.0, 0.9)]
    floors = [dict(_rec("a", "-", 50.0, 0.01), kind="floor"), dict(_rec("c", "-", 60.0, 0.02, "RGL"), kind="floor")]
    lines = bench.summarise(records, floors, ["auto", "constant"])
    text = "\n".join(lines)
    auto = next(x for x in lines if x.strip().startswith("auto"))
    assert "PSNR median  35.0 / worst  30.0 dB (a)" in auto and "linear  20.0 /   60.0 %" in auto
    assert "linear > 50 %: 1;" in auto and "[3]" in auto  # no count without the brightest pixel: records lack it
    for r in records:  # b's error is its highlight's pixel
        r["linear_but_brightest"] = 0.1 if r["material"] == "b" else r["linear"]
    auto = next(x for x in bench.summarise(records, floors, ["auto", "constant"]) if x.strip().startswith("auto"))
    assert "linear > 50 %: 1 (0 without the truth's brightest pixel)" in auto
    assert not any("oracle" in x for x in lines)  # one single method (constant is none): no oracle
    two = records + [_rec("a", "fit", 33.0, 0.1), _rec("b", "fit", 20.0, 0.1), _rec("a", "revolve", 31.0, 0.1),
                     _rec("b", "revolve", 25.0, 0.1)]
    oracle = next(x for x in bench.summarise(two, floors, ["auto", "fit", "revolve"]) if "oracle" in x)
    assert "the best of fit, revolve per material" in oracle and "median  29.0 / worst  25.0 dB [2]" in oracle
    assert "    MERL                     PSNR median  35.0 / worst  30.0 dB (a)" in text  # a and b
    assert "    RGL                      PSNR median  35.0 / worst  35.0 dB (c)" in text
    assert "  all                      PSNR median  55.0 / worst  50.0 dB (a)" in text  # the floor


@pytest.mark.slow
def test_the_prior_floor_benchmark_runs_on_a_data_folder(tmp_path, capsys, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path / "cache"))
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_prior_floor.py"
    spec = importlib.util.spec_from_file_location("bench_prior_floor", path)
    floor = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(floor)
    data = tmp_path / "realdata"
    (data / "nbrdf-merl").mkdir(parents=True)
    for k in range(4):
        write_nbrdf(data / "nbrdf-merl" / f"synthetic-{k}", k)
    assert floor.main(["--data", str(data), "--materials", "synthetic-0,synthetic-1"]) == 0
    out = capsys.readouterr().out
    for case in ("all", "theta_d<60", "slice 40", "slices 20/40/60", "slices 40/70"):
        assert f"  {case} " in out
    from reconstruction.methods.prior import load_prior

    ps = load_prior(data / "nbrdf-merl")
    f = floor.floors(ps, 0, floor.cell_sets())
    assert all(np.isfinite(v) and v >= 0 for v in f.values())
    assert f["all"] < 0.5 * f["slice 40"]  # fitted to every cell, far closer than from one slice's cells
    assert floor.main(["--data", str(data), "--materials", "nope"]) == 2
    # --image: the floors judged by renders, over both folders (a basis of the other materials of the two)
    assert floor.main(["--data", str(data), "--image"]) == 2  # no nbrdf-extra yet
    assert "nbrdf-extra" in capsys.readouterr().err
    (data / "nbrdf-extra").mkdir()
    # the search over K and the ridge weight on two of each (the benchmark's twelve pairs: the same code, 3 times
    # the renders; the search itself is what the next lines check: the best of the candidates is kept)
    monkeypatch.setattr(floor, "IMAGE_K", floor.IMAGE_K[:2])
    monkeypatch.setattr(floor, "IMAGE_LAM", floor.IMAGE_LAM[:2])
    for k in range(4, 6):
        write_nbrdf(data / "nbrdf-extra" / f"rgl-synthetic-{k}", k)
    assert floor.main(["--data", str(data), "--image", "--size", "16", "--workers", "1", "--materials",
                       "synthetic-1,synthetic-2", "--every", "2"]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines() if line.startswith(("rgl-synthetic-", "synthetic-"))]
    assert [r[0] for r in rows] == ["synthetic-1"]  # every second of the two named
    for r in rows:
        db = [float(v) for v in r[1::2]]  # all, slice 40, slices 40/70, slices 20/40/60 (dB)
        assert len(db) == 4 and all(np.isfinite(v) and v > 0 for v in db)
        assert db[0] > db[1]  # every cell known: a closer render than from one slice's cells
    assert "a basis of the other 5 each" in out and "slices 40/70     median" in out


def test_the_docs_page_leads_with_the_image_metric_and_keeps_its_notes(bench, tmp_path):
    recs = [_rec("a", "auto", 31.0, 0.2), _rec("b", "auto", 41.0, 0.4, "RGL")]
    bench.write_docs(recs, [], ["auto"], tmp_path, ["SUMMARY LINE"], "CMD --docs docs")
    first = (tmp_path / "real-materials.md").read_text(encoding="utf-8")
    assert first.splitlines()[2].startswith("Regenerate: `CMD --docs docs`")
    assert "SUMMARY LINE" in first and "| a | MERL | 31.0 / 20 % [] |" in first
    head = first.split("## Summary")[0]
    assert "**PSNR**" in head and "| 1 slice(s) at 40 deg | auto | 36.0 / 31.0 | 30 % / 40 % |" in head
    assert "(real-materials.png)" in head
    assert bench.NOTES_BEGIN in first and "No notes yet" in first  # a new page gets a placeholder block
    notes = f"{bench.NOTES_BEGIN}\nTwo slices at 40/70 deg beat three (`some --command`).\n{bench.NOTES_END}"
    (tmp_path / "real-materials.md").write_text(first.replace(bench.kept_notes(tmp_path / "real-materials.md"), notes),
                                                encoding="utf-8")
    bench.write_docs([dict(r, psnr_db=20.0) for r in recs], [], ["auto"], tmp_path, ["NEW SUMMARY"], "CMD")
    second = (tmp_path / "real-materials.md").read_text(encoding="utf-8")
    assert "NEW SUMMARY" in second and "SUMMARY LINE" not in second  # the figures are rewritten ...
    assert second.count(notes) == 1 and "No notes yet" not in second  # ... the notes kept, once


def test_the_peak_isotropy_benchmark(tmp_path, capsys):
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_peak_isotropy.py"
    spec = importlib.util.spec_from_file_location("bench_peak_isotropy", path)
    iso = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(iso)
    from reconstruction.core.models import Material

    ggx = Material.from_dict({"name": "g", "lobes": [{"type": "lambert", "albedo": 0.1},
                                                     {"type": "ggx", "alpha": 0.01, "specular": 1.0}]})
    peak, inp, across = iso.peak_ratios(ggx, 40.0, 0.25)
    assert peak > inp > 0.1  # 0.25 deg off the mirror's half vector: on the lobe's shoulder
    assert across == pytest.approx(inp, rel=0.02)  # a lobe of theta_h alone: alike across the plane and in it
    assert iso.main(["--data", str(tmp_path)]) == 2 and "nbrdf-merl" in capsys.readouterr().err
    (tmp_path / "nbrdf-merl").mkdir()
    for k in range(2):
        write_nbrdf(tmp_path / "nbrdf-merl" / f"synthetic-{k}", k)
    assert iso.main(["--data", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "synthetic-0" in out and "synthetic-1" in out and "2 materials; ratio median" in out


@pytest.mark.slow
def test_the_speed_benchmark_times_a_prior_first_from_an_empty_cache(tmp_path):
    """bench_speed --prior: the first run tabulates the folder into a fresh cache (its bytes counted), the second
    reads it; a run that fails ends the benchmark with its error."""
    path = Path(__file__).resolve().parents[1] / "benchmarks" / "bench_speed.py"
    spec = importlib.util.spec_from_file_location("bench_speed", path)
    speed = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(speed)
    from tests.test_cli_reconstruct import BLUE_PLASTIC, slice_file

    folder = tmp_path / "prior"
    folder.mkdir()
    for k in range(3):
        write_nbrdf(folder / f"synthetic-{k}", k)
    capture = tmp_path / "demo"
    capture.mkdir()
    slice_file(capture / "slice.csv", BLUE_PLASTIC)
    work = tmp_path / "work"
    work.mkdir()
    first, again, size = speed.prior_runs(capture, work, [folder])
    assert first[0] > 0 and again[0] > 0 and first[1] > 0
    cached = list((work / "cache").rglob("*"))
    assert size == sum(p.stat().st_size for p in cached if p.is_file()) and size > 1000
    with pytest.raises(SystemExit, match="failed"):
        speed.prior_runs(capture, work, [tmp_path / "nowhere"])
