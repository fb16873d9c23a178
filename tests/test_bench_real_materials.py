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
    assert bench.incidences_of("3") == (20.0, 40.0, 60.0)
    assert bench.incidences_of("20/50/75") == (20.0, 50.0, 75.0)
    assert bench.incidences_of("70") == (70.0,)
    assert bench._label("40/70") == "2 slice(s) at 40/70 deg"
    for bad, why in (("x", "expected 1, 3 or incidences"), ("20/95", "0..80"), ("20//50", "expected")):
        with pytest.raises(ValueError, match=why):
            bench.incidences_of(bad)


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
    for k, name in enumerate(("synthetic-a", "synthetic-b")):
        write_nbrdf(data / "nbrdf-merl" / name, k)
    out = tmp_path / "records.jsonl"
    args = ["--data", str(data), "--methods", "bivariate", "--workers", "1", "--cache", "", "--prior", "",
            "--jsonl", str(out)]
    assert bench.main(args + ["--slices", "1,30/60"]) == 0
    recs = [json.loads(line) for line in out.read_text().splitlines()]
    assert sorted((r["material"], r["slices"]) for r in recs) == [
        ("synthetic-a", "1"), ("synthetic-a", "30/60"), ("synthetic-b", "1"), ("synthetic-b", "30/60")]
    assert all(np.isfinite(r["rmse80"]) and r["plausible"] for r in recs)
    # two slices see more of each material than one
    by = {(r["material"], r["slices"]): r["rmse80"] for r in recs}
    assert all(by[(m, "30/60")] < by[(m, "1")] for m in ("synthetic-a", "synthetic-b"))
    capsys.readouterr()
    assert bench.main(args + ["--slices", "1,95"]) == 2
    assert "--slices" in capsys.readouterr().err


def test_the_summary_counts_auto_against_the_best_method_and_bounds_any_choice(bench):
    def rec(material, method, e):
        return {"material": material, "slices": "1", "method": method, "rmse80": e, "medrel": e, "plausible": True,
                "seconds": 0.1, "max_albedo": 0.5}

    records = [rec("a", "auto", 0.20), rec("a", "fit", 0.19), rec("a", "revolve", 0.40),   # within 10 %
               rec("b", "auto", 0.60), rec("b", "fit", 0.30), rec("b", "revolve", 0.90),   # not
               rec("c", "auto", 0.70), rec("c", "fit", 0.80), rec("c", "revolve", 0.65)]   # within
    lines = "\n".join(bench.summarise(records, ["auto", "fit", "revolve"]))
    assert "within 10 % (relative) of the best method's rmse80: 2 of 3" in lines
    # the best per material: 19, 30, 65 %
    assert "chosen with the truth, a bound on any choice): rmse80 median 30.0 %, worst 65.0 %, > 50 %: 1" in lines


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


def test_the_docs_page_keeps_its_hand_written_notes(bench, tmp_path):
    recs = [{"material": m, "slices": "1", "method": "auto", "rmse80": e, "medrel": e, "plausible": True,
             "used": "prior", "seconds": 0.1} for m, e in (("a", 0.2), ("b", 0.4))]
    bench.write_docs(recs, ["auto"], tmp_path, ["SUMMARY LINE"])
    first = (tmp_path / "real-materials.md").read_text(encoding="utf-8")
    assert "SUMMARY LINE" in first and "| a | 20.0 / 20.0 [prior] |" in first
    assert bench.NOTES_BEGIN in first and "No notes yet" in first  # a new page gets a placeholder block
    notes = f"{bench.NOTES_BEGIN}\nTwo slices at 40/70 deg beat three (`some --command`).\n{bench.NOTES_END}"
    (tmp_path / "real-materials.md").write_text(first.replace(bench.kept_notes(tmp_path / "real-materials.md"), notes),
                                                encoding="utf-8")
    bench.write_docs([dict(r, rmse80=0.3) for r in recs], ["auto"], tmp_path, ["NEW SUMMARY"])
    second = (tmp_path / "real-materials.md").read_text(encoding="utf-8")
    assert "NEW SUMMARY" in second and "SUMMARY LINE" not in second  # the figures are rewritten ...
    assert second.count(notes) == 1 and "No notes yet" not in second  # ... the notes kept, once
