"""The speed/accuracy trade study behind ``gonio-sim study``.

Every case is a real simulated capture: a bench config is derived from the base config (material, plan,
noise), ``gonio-capture`` runs it as a child process against ``gonio-sim serve`` (bytes on pseudo-terminals,
simulated time as fast as possible), and every reconstruction method is run on the captured slice. A case
records the capture time (``capture_time_s``: the time model's estimate, what ``gonio-capture --check`` tells
for that plan, with adaptive refinement's rounds as they were planned; the study chooses plans by it), the
simulated bench time it took (``bench_time_s``; the two are one model, :mod:`reconstruction.instrument.timing`, and a
case where they differ by more than 5 % is logged), the reconstruction time and the errors of the full table
against the material's own table (``reconstruction.core.metrics.table_errors``).

Cases run through a ``concurrent.futures`` executor (``reconstruction.executor``): local processes by default,
a Dask cluster with ``--scheduler``. Results go to ``OUT/<name>.csv`` (every row), ``OUT/<name>-pareto.png`` and
the ``<name>`` section of the one study page ``OUT/study.md`` (Pareto fronts and recommendations per error budget).
"""

from __future__ import annotations

import csv
import itertools
import json
import logging
import math
import os
import shutil
import subprocess
import sys
import time
import zlib
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any

import numpy as np

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

log = logging.getLogger("simulator.study")

#: Ground-truth materials of the study (a photodiode bench sees one band: its captures are judged in that band).
MATERIALS: dict[str, dict[str, Any]] = {
    "diffuse": {"name": "diffuse", "lobes": [{"type": "lambert", "albedo": 0.6}]},
    "glossy-ggx": {"name": "glossy-ggx", "lobes": [
        {"type": "lambert", "albedo": 0.2},
        {"type": "ggx", "alpha": 0.15, "specular": 0.8, "f0": 0.04}]},
    "sharp-ggx": {"name": "sharp-ggx", "lobes": [
        {"type": "lambert", "albedo": 0.1},
        {"type": "ggx", "alpha": 0.02, "specular": 0.9, "f0": 0.04}]},
    "back-scatter": {"name": "back-scatter", "lobes": [
        {"type": "lambert", "albedo": 0.15},
        {"type": "ggx", "alpha": 0.25, "specular": 0.5},
        {"type": "retro", "exponent": 12.0, "amount": 0.3}]},
    "rough-oren-nayar": {"name": "rough-oren-nayar", "lobes": [
        {"type": "oren_nayar", "albedo": 0.7, "sigma_deg": 30.0}]},
    # the mirror-like sample: a lobe 0.06 deg wide inside the detector's 1 deg cone
    "mirror": {"name": "mirror", "lobes": [
        {"type": "lambert", "albedo": 0.02},
        {"type": "ggx", "alpha": 0.001, "specular": [0.97, 0.95, 0.9]}]},
}

#: Incidence angles (deg) used for a given number of slices.
INCIDENCES: dict[int, list[float]] = {
    1: [30.0],
    2: [20.0, 50.0],
    4: [10.0, 30.0, 50.0, 70.0],
    8: [5.0, 15.0, 25.0, 35.0, 45.0, 55.0, 65.0, 75.0],
}

#: Noise levels: overrides of [simulator] (source_power sets the photon count, so the shot noise).
NOISE: dict[str, dict[str, float]] = {
    "low": {"source_power": 1.0e7, "read_noise": 5.0},
    "high": {"source_power": 2.0e5, "read_noise": 20.0},
}

#: The order in which the study lists the methods of the registry (a method registered later comes after them).
_METHOD_ORDER = ("fit", "microfacet", "bivariate", "revolve")


def _study_methods() -> tuple[str, ...]:
    """Every method of the reconstruction's registry that needs nothing beyond the slices (not ``prior``, which
    needs a folder of prior materials), then ``auto``."""
    from reconstruction.methods import REGISTRY, Options

    usable = [m for m, spec in REGISTRY.items() if spec.usable(Options())]
    known = [m for m in _METHOD_ORDER if m in usable] + [m for m in usable if m not in _METHOD_ORDER]
    return (*known, "auto")


METHODS: tuple[str, ...] = _study_methods()
BUDGETS: tuple[float, ...] = (0.02, 0.05, 0.10)
FIELDS = ["material", "step_deg", "n_slices", "repeats", "plan", "noise", "method", "method_used", "status",
          "samples", "capture_time_s", "bench_time_s", "auto_range_s", "capture_wall_s", "recon_time_s",
          "rel_rmse_cos", "rmse80", "log_rmse", "sphere_rel_error", "albedo_max_abs_error", "error"]
#: The reduced grid (``--reduced``): one slice and four slices, 2 deg steps, 4 repeats, low noise.
REDUCED_SETTINGS = [(2.0, 1, 4, "uniform", "low"), (2.0, 4, 4, "uniform", "low")]


def materials_from_dir(folder: str | Path) -> dict[str, dict[str, Any]]:
    """The study materials of ``folder``: every neural BRDF set (``NAME_fc1.npy`` ... ``NAME_b3.npy``, as in
    ../shared/realdata/nbrdf-merl) as an ``nbrdf`` material named NAME, and every ``*.toml`` with a ``[material]``
    table (named after its ``name`` or the file). Paths become absolute, so the case configs work anywhere.
    Raises ValueError naming the file for a bad material, or when the folder holds none."""
    from reconstruction.core.models import NBRDF_SUFFIXES, Material, MaterialError

    d = Path(folder)
    if not d.is_dir():
        raise ValueError(f"{d}: not a folder")
    out: dict[str, dict[str, Any]] = {}
    first = f"_{NBRDF_SUFFIXES[0]}.npy"
    for p in sorted(d.glob(f"*{first}")):
        name = p.name[: -len(first)]
        if all((d / f"{name}_{x}.npy").is_file() for x in NBRDF_SUFFIXES):
            out[name] = {"name": name, "lobes": [{"type": "nbrdf", "path": str((d / name).resolve())}]}
    for p in sorted(d.glob("*.toml")):
        try:
            data = tomllib.loads(p.read_text(encoding="utf-8"))
        except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as e:
            raise ValueError(f"{p}: not a readable TOML file ({e})") from None
        if "material" not in data:
            continue
        try:
            Material.from_dict(data["material"], p.parent, source=f"{p}: [material]")  # validated as the bench will
        except MaterialError as e:
            raise ValueError(str(e)) from None
        mat = json.loads(json.dumps(data["material"]))
        for lobe in mat.get("lobes", []):
            if isinstance(lobe.get("path"), str) and not Path(lobe["path"]).is_absolute():
                lobe["path"] = str((p.parent / lobe["path"]).resolve())
        out[str(mat.get("name") or p.stem)] = mat
    if not out:
        raise ValueError(f"{d}: no neural BRDF (NAME_fc1.npy ...) and no material TOML file inside")
    return out


@dataclass(frozen=True)
class Case:
    """One simulated capture: material, outgoing step (deg), number of incidence slices, repeats per point,
    plan kind ("uniform" or "adaptive") and noise level ("low" or "high")."""

    material: str
    step_deg: float
    n_slices: int
    repeats: int
    plan: str
    noise: str

    @property
    def name(self) -> str:
        return (f"{self.material}_s{self.step_deg:g}_n{self.n_slices}_r{self.repeats}_{self.plan}_{self.noise}"
                .replace(".", "p"))

    @property
    def seed(self) -> int:
        return zlib.crc32(self.name.encode()) & 0x7FFFFFFF


def grid(quick: bool = False, materials: Sequence[str] | None = None,
         catalogue: dict[str, dict[str, Any]] | None = None, reduced: bool = False) -> list[Case]:
    """The study's cases. Full: every combination of step (0.5, 1, 2, 5 deg), slices (1, 2, 4, 8), repeats
    (1, 4, 16), plan (uniform, adaptive) and noise (low, high) for each material. Quick: four settings that
    span cheap to expensive, per material; reduced: :data:`REDUCED_SETTINGS`. ``catalogue``: the materials to
    choose from (default :data:`MATERIALS`; e.g. :func:`materials_from_dir`)."""
    known = catalogue if catalogue is not None else MATERIALS
    mats = list(materials or known)
    unknown = [m for m in mats if m not in known]
    if unknown:
        raise ValueError(f"unknown material(s) {unknown}; choose from {sorted(known)}")
    if reduced:
        settings = list(REDUCED_SETTINGS)
    elif quick:
        settings = [(5.0, 1, 1, "uniform", "low"), (2.0, 2, 4, "uniform", "low"),
                    (2.0, 1, 4, "adaptive", "low"), (2.0, 4, 4, "uniform", "high")]
    else:
        settings = list(itertools.product((0.5, 1.0, 2.0, 5.0), (1, 2, 4, 8), (1, 4, 16), ("uniform", "adaptive"),
                                          ("low", "high")))
    return [Case(m, *s) for m in mats for s in settings]


#: Measured on the 2-core development machine (the real-materials study: 96 captures in 959 s with 2 workers,
#: the quick study): seconds of work per case besides its samples, and per captured sample.
CASE_SECONDS, SAMPLE_SECONDS = 17.0, 0.004


def estimate_seconds(cases: Sequence[Case], workers: int) -> float:
    """A rough wall time (s) for ``cases`` on ``workers`` processes: a fixed cost per case (five reconstructions,
    their tables and error figures) plus the capture's samples (outgoing step, slices, repeats)."""
    total = 0.0
    for c in cases:
        samples = c.n_slices * (160.0 / c.step_deg + 1.0)
        total += CASE_SECONDS + SAMPLE_SECONDS * samples * (1.0 + 0.1 * c.repeats)
    return total / max(1, workers)


def case_config(base: dict[str, Any], case: Case, material: dict[str, Any] | None = None) -> dict[str, Any]:
    """The bench config dict of ``case``: ``base`` (a parsed simulated bench file) with its material (``material``,
    default the study's own of that name), plan, repeats, noise and seed replaced; simulated time runs as fast as
    possible."""
    cfg = json.loads(json.dumps(base))  # deep copy of plain TOML data
    cfg["material"] = material if material is not None else MATERIALS[case.material]
    plan = {k: v for k, v in cfg.get("plan", {}).items() if k not in ("adaptive", "theta_i_min_deg",
                                                                       "theta_i_max_deg", "theta_i_step_deg")}
    plan.update(theta_i_deg=INCIDENCES[case.n_slices], theta_o_step_deg=case.step_deg, repeats=case.repeats)
    if case.plan == "adaptive":
        coarse = min(max(4 * case.step_deg, 5.0), 10.0)
        plan["theta_o_step_deg"] = coarse
        plan["adaptive"] = {"coarse_step_deg": coarse, "min_step_deg": case.step_deg, "tolerance": 0.05}
    elif case.plan != "uniform":
        raise ValueError(f"case {case.name}: plan must be 'uniform' or 'adaptive', got {case.plan!r}")
    cfg["plan"] = plan
    cfg.setdefault("detector", {})["repeats"] = case.repeats
    sim = cfg.setdefault("simulator", {})
    sim.update(NOISE[case.noise], seed=case.seed, time_scale=0.0)
    return cfg


@lru_cache(maxsize=8)
def _truth(material_json: str) -> Any:
    from reconstruction.core import merltable
    from reconstruction.core.models import Material

    return merltable.tabulate(Material.from_dict(json.loads(material_json)).eval, supersample="adaptive")


def truth_table(material: str | dict[str, Any]) -> Any:
    """The material's own MERL table (bin centres, adaptive cell averages where lobes are sharp); cached.
    ``material``: a study material's name or a material dict."""
    d = MATERIALS[material] if isinstance(material, str) else material
    return _truth(json.dumps(d, sort_keys=True))


truth_table.cache_clear = _truth.cache_clear  # type: ignore[attr-defined]


def capture_estimate_s(summary: dict[str, Any]) -> float:
    """The time model's estimate (s) of a capture from its ``gonio-capture --json`` summary: the estimate before
    refinement plus the refinement rounds' as planned (the simulated bench time for a summary without one)."""
    est = float(summary.get("estimate_s") or 0.0) + float(summary.get("estimate_refinement_s") or 0.0)
    return est if est > 0 else float(summary["bench_time_s"])


def recorded_times(cap_dir: Path) -> dict[str, float]:
    """``bench_time_s``, ``auto_range_s`` and ``capture_time_s`` (s) of a capture from its ``capture.json``: every
    run's bench time, auto-ranging overhead, and the time model's estimate of the capture (the last run's
    ``estimate.total_s``, which counts the runs before it). For a complete capture that a study reuses: resuming
    it does nothing, so its summary says 0 s."""
    rec = json.loads((cap_dir / "capture.json").read_text(encoding="utf-8"))
    runs = rec.get("runs") or []
    bench = float((rec.get("totals") or {}).get("bench_time_s") or sum(float(r.get("bench_time_s") or 0.0)
                                                                        for r in runs))
    ranging = sum(float((r.get("auto_range") or {}).get("overhead_s") or 0.0) for r in runs)
    est = float((rec.get("estimate") or {}).get("total_s") or 0.0)
    return {"bench_time_s": bench, "auto_range_s": ranging, "capture_time_s": est if est > 0 else bench}


def photodiode_weights(cfg_path: Path) -> np.ndarray:
    """(3,) weights of a linear-sRGB material's R, G, B in the photodiode's one channel of the bench ``cfg_path``
    (its responsivity x source spectrum over the Mallett-Yuksel spectra of R, G, B; they sum to 1); the mean when
    the bench names no band."""
    from reconstruction.schema.optics import BAND_NM
    from simulator.config import load_config
    from simulator.world.physics import _srgb_basis

    w = load_config(cfg_path).detector.band_weights
    return np.full(3, 1.0 / 3.0) if w is None else np.asarray(w, float) @ _srgb_basis(BAND_NM)


def run_case(job: tuple[Case, str, str]) -> list[dict[str, Any]]:
    """Capture ``case`` on the simulator and reconstruct it with every method; one result row per method.

    ``job`` = (case, base config TOML text, work directory[, material dict]). Runs in a worker process, possibly
    on another machine of a Dask cluster: the config travels as text and the rows come back as data; captures go
    to the work directory where the worker can write it, else to a temporary folder. Never raises for a failed
    capture or method: the row says what failed.
    """
    case, base_text, workdir = job[:3]
    material = job[3] if len(job) > 3 else MATERIALS[case.material]  # type: ignore[misc]
    import tempfile

    import tomli_w

    try:
        out = Path(workdir) / case.name
        out.mkdir(parents=True, exist_ok=True)
    except OSError:  # the client's path does not exist on this worker
        out = Path(tempfile.mkdtemp(prefix=f"gonio-study-{case.name}-"))
    base = tomllib.loads(base_text)
    cfg_path = out / "bench.toml"
    cfg_text = tomli_w.dumps(case_config(base, case, material))
    cap_dir = out / "capture"
    if cap_dir.exists() and (not cfg_path.exists() or cfg_path.read_text(encoding="utf-8") != cfg_text):
        shutil.rmtree(cap_dir)  # captured with another config (material, noise, plan): start again
    cfg_path.write_text(cfg_text, encoding="utf-8")
    row0: dict[str, Any] = {**asdict(case), "status": "ok", "error": ""}
    t0 = time.perf_counter()
    proc = subprocess.run(
        [sys.executable, "-m", "acquisition.cli", "--config", str(cfg_path), "--out", str(cap_dir),
         "--json", "--no-progress", "--log-level", "error"] + (["--resume"] if cap_dir.exists() else []),
        capture_output=True, text=True, timeout=3600)
    row0["capture_wall_s"] = time.perf_counter() - t0
    try:
        summary = json.loads(proc.stdout.strip().splitlines()[-1])
    except (IndexError, json.JSONDecodeError):
        summary = {}
    if proc.returncode != 0 or summary.get("status") != "complete":
        msg = (proc.stderr.strip().splitlines() or ["no output"])[-1]
        return [{**row0, "method": m, "status": "capture failed", "error": msg} for m in METHODS]
    row0["bench_time_s"] = float(summary["bench_time_s"])
    row0["auto_range_s"] = float(summary.get("auto_range_overhead_s") or 0.0)
    row0["capture_time_s"] = capture_estimate_s(summary)
    if row0["bench_time_s"] <= 0.0:  # an earlier study's complete capture, resumed: this run did nothing
        row0.update(recorded_times(cap_dir))
    foreseeable = row0["bench_time_s"] - row0["auto_range_s"]  # what ranging costs depends on the sample
    if abs(row0["capture_time_s"] - foreseeable) > 0.05 * foreseeable:
        log.warning("case %s: the time model's estimate %.2f s and the simulated bench time %.2f s (less %.2f s of "
                    "auto-ranging) differ by more than 5 %%", case.name, row0["capture_time_s"],
                    row0["bench_time_s"], row0["auto_range_s"])
    row0["samples"] = int(summary["samples_total"])

    from reconstruction import pipeline
    from reconstruction.core import metrics
    from reconstruction.formats.inputs import load_inputs

    s = load_inputs([cap_dir / "slice.csv"]).slice
    truth = truth_table(material)
    if len(s.channels) == 1:  # a photodiode sees one band: judge against the same band
        truth = np.broadcast_to(np.tensordot(photodiode_weights(cfg_path), truth, axes=1)[None], truth.shape)
    rows = []
    for method in METHODS:
        row = {**row0, "method": method}
        try:
            t1 = time.perf_counter()
            rec, choice = pipeline.reconstruct(s, method)
            table = pipeline.tabulate(rec)
            row["recon_time_s"] = time.perf_counter() - t1
            row["method_used"] = choice["used"]
            row.update(metrics.table_errors(table, truth))
            row["rmse80"] = metrics.relative_rmse_cos(table, truth, max_theta_deg=80.0)
        except Exception as e:  # noqa: BLE001 - a failed method is a result of the study, not a crash
            row.update(status="method failed", error=f"{type(e).__name__}: {e}")
        rows.append(row)
    return rows


# --- summaries -------------------------------------------------------------------------------------------


def _ok(rows: Iterable[dict[str, Any]]) -> list[dict[str, Any]]:
    return [r for r in rows if r.get("status") == "ok" and math.isfinite(float(r.get("rel_rmse_cos", math.inf)))]


def pareto_front(rows: Sequence[dict[str, Any]], x: str = "capture_time_s", y: str = "rel_rmse_cos"
                 ) -> list[dict[str, Any]]:
    """Rows not dominated in (``x``, ``y``), both smaller-is-better, sorted by ``x``."""
    front: list[dict[str, Any]] = []
    best = math.inf
    for r in sorted(rows, key=lambda r: (float(r[x]), float(r[y]))):
        if float(r[y]) < best:
            front.append(r)
            best = float(r[y])
    return front


def recommend(rows: Sequence[dict[str, Any]], budget: float, metric: str = "rel_rmse_cos"
              ) -> dict[str, dict[str, Any] | None]:
    """Per material, the row with the least capture time whose error ``metric`` (relative RMSE of f cos cos over
    the table, or ``rmse80``: within 80 deg) is within ``budget``."""
    out: dict[str, dict[str, Any] | None] = {}
    for m in sorted({r["material"] for r in rows}):
        ok = [r for r in _ok(rows) if r["material"] == m and float(r.get(metric, math.inf)) <= budget]
        out[m] = min(ok, key=lambda r: (float(r["capture_time_s"]), float(r[metric]))) if ok else None
    return out


def _setting(r: dict[str, Any]) -> str:
    return (f"step {float(r['step_deg']):g} deg, {r['n_slices']} slice(s), {r['repeats']} repeat(s), "
            f"{r['plan']}, {r['noise']} noise")


def write_csv(path: Path, rows: Sequence[dict[str, Any]]) -> None:
    with open(path, "w", newline="", encoding="utf-8") as fh:
        w = csv.DictWriter(fh, fieldnames=FIELDS, extrasaction="ignore")
        w.writeheader()
        for r in rows:
            w.writerow({k: (f"{v:.6g}" if isinstance(v, float) else v) for k, v in r.items()})


#: The one study page in OUT: every study (``--name``) is a section of it, between markers that ``gonio-sim study``
#: rewrites; the text outside them (the page's introduction, how to rerun) is kept. Every row is in ``OUT/NAME.csv``.
STUDY_PAGE = "study.md"
#: The section titles of the studies committed in docs/ (another name is its own title).
TITLES = {"study": "The full grid", "study-quick": "The quick grid", "study-real-materials": "The measured materials"}
_INTRO = ["# Speed/accuracy study", "", "Figures on this page come from `gonio-sim study` (each section names its "
          "command). Capture time is simulated bench time (motion, settling, integration, dark "
          "and white-reference readings); errors are against the material's own table: relative RMSE of f "
          "cos(theta_i) cos(theta_o) over all valid cells, RMSE of its logarithm, relative error of the rendered "
          "preview sphere, and the largest directional-albedo error over theta_i = 0..80 deg. Every row (capture x "
          "method) is in the study's CSV; this page holds its recommendations, Pareto fronts and plot.", ""]


def _markers(name: str) -> tuple[str, str]:
    return (f"<!-- study {name}: written by gonio-sim study, edits between these markers are lost -->",
            f"<!-- end of study {name} -->")


def study_section(text: str, name: str) -> str | None:
    """The section of study ``name`` in the study page ``text`` (markers included), or None."""
    begin, end = _markers(name)
    i, j = text.find(begin), text.find(end)
    return text[i:j + len(end)] if 0 <= i < j else None


def _budget_cell(r: dict[str, Any] | None, ok: Sequence[dict[str, Any]], m: str, metric: str) -> str:
    if r is None:
        best = min((float(x.get(metric, math.inf)) for x in ok if x["material"] == m), default=math.inf)
        return f"not reached (best {best:.1%})"
    return f"{float(r['capture_time_s']):.1f} s: {r['method']}, {_setting(r)} ({float(r[metric]):.2%})"


def section_lines(rows: Sequence[dict[str, Any]], name: str, command: str, metric: str = "rel_rmse_cos",
                  merged: str = "") -> list[str]:
    """The section of study ``name``: its command, counts, plot, recommendations per budget and Pareto fronts."""
    ok = _ok(rows)
    what = ("relative RMSE of f cos cos over the cells with both angles <= 80 deg (rmse80)" if metric == "rmse80"
            else "relative RMSE of f cos cos")
    failed = [r for r in rows if r.get("status") != "ok"]
    title = TITLES.get(name, name)
    lines = [_markers(name)[0], f"## {title} ({name})" if name in TITLES else f"## {name}", "",
             f"Produced by `{command}`."]
    if merged:
        lines += [merged]
    lines += [f"{len(rows)} rows ({len({_setting(r) + r['material'] for r in rows})} captures), {len(failed)} "
              f"failed: [{name}.csv]({name}.csv).", "", f"![error against capture time, {title.lower()}]"
              f"({name}-pareto.png)", "", "### Recommendations", "",
              f"The least capture time that reaches an error budget ({what}), per material:", "",
              "| material | " + " | ".join(f"budget {b:.0%}" for b in BUDGETS) + " |",
              "|---" * (len(BUDGETS) + 1) + "|"]
    recs = [recommend(rows, b, metric) for b in BUDGETS]
    for m in sorted({r["material"] for r in rows}):
        cells = [_budget_cell(rec[m], ok, m, metric) for rec in recs]
        lines.append(f"| {m} | " + " | ".join(["the same" if k and c == cells[k - 1] else c
                                                  for k, c in enumerate(cells)]) + " |")
    lines += ["", "### Pareto fronts (capture time vs error)", ""]
    for m in sorted({r["material"] for r in ok}):
        front = pareto_front([r for r in ok if r["material"] == m])
        lines.append(f"- **{m}**: " + "; ".join(
            f"{float(r['capture_time_s']):.0f} s -> {float(r['rel_rmse_cos']):.2%} ({r['method']}, {_setting(r)})"
            for r in front))
    return lines + [_markers(name)[1]]


def write_markdown(path: Path, rows: Sequence[dict[str, Any]], name: str, command: str,
                   metric: str = "rel_rmse_cos", merged: str = "") -> None:
    """Write the section of study ``name`` into the study page at ``path`` (:data:`STUDY_PAGE`): the section is
    replaced where it is, or added at the end; the rest of the page is kept (a new page gets an introduction).
    ``merged``: a sentence saying which rows come from an earlier run (``--merge``)."""
    text = path.read_text(encoding="utf-8") if path.exists() else "\n".join(_INTRO) + "\n"
    new = "\n".join(section_lines(rows, name, command, metric, merged))
    old = study_section(text, name)
    text = text.replace(old, new) if old is not None else text.rstrip("\n") + "\n\n" + new + "\n"
    path.write_text(text, encoding="utf-8")


def draw_front(ax: Any, front: Sequence[dict[str, Any]]) -> Any:
    """The Pareto front on ``ax``: a step line through its points, each ringed, so that a front of one point (a
    step of no length) shows as well. Returns the line."""
    (line,) = ax.step([float(r["capture_time_s"]) for r in front],
                      [max(float(r["rel_rmse_cos"]), 1e-4) for r in front], where="post", color="k", lw=1,
                      marker="o", markersize=9, markerfacecolor="none", markeredgewidth=1.0, label="Pareto front")
    return line


def write_plot(path: Path, rows: Sequence[dict[str, Any]], title: str) -> None:
    """Error against capture time, one panel per material, one marker per method, Pareto front drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib import ticker

    ok = _ok(rows)
    mats = sorted({r["material"] for r in ok})
    if not mats:
        return
    ncol = min(3, len(mats))
    nrow = math.ceil(len(mats) / ncol)
    fig, axes = plt.subplots(nrow, ncol, figsize=(4.2 * ncol, 3.4 * nrow), squeeze=False)
    markers = {"fit": "o", "microfacet": "D", "bivariate": "s", "revolve": "^", "auto": "*"}
    for ax, m in zip(axes.flat, mats, strict=False):
        mr = [r for r in ok if r["material"] == m]
        for method in METHODS:
            pts = [r for r in mr if r["method"] == method]
            ax.scatter([float(r["capture_time_s"]) for r in pts], [max(float(r["rel_rmse_cos"]), 1e-4) for r in pts],
                       marker=markers.get(method, "x"), label=method, alpha=0.7, s=22)
        draw_front(ax, pareto_front(mr))
        for b in BUDGETS:
            ax.axhline(b, color="grey", lw=0.5, ls=":")
        ax.set_xscale("log")
        ax.set_yscale("log")
        ax.xaxis.set_major_locator(ticker.LogLocator(base=10, subs=(1.0, 2.0, 5.0)))
        ax.xaxis.set_major_formatter(ticker.FuncFormatter(lambda v, _: f"{v:g}"))
        ax.xaxis.set_minor_formatter(ticker.NullFormatter())
        ax.set_title(m, fontsize=10)
        ax.set_xlabel("simulated capture time (s)")
        ax.set_ylabel("relative RMSE of f cos cos")
    for ax in list(axes.flat)[len(mats):]:
        ax.axis("off")
    axes.flat[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=11)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def read_rows(path: str | Path) -> list[dict[str, Any]]:
    """The rows of a study CSV (``write_csv``'s columns; an earlier run's missing columns stay missing). Raises
    ValueError naming the file when it is not a study CSV."""
    p = Path(path)
    try:
        with open(p, newline="", encoding="utf-8") as fh:
            rows = list(csv.DictReader(fh))
    except (OSError, UnicodeDecodeError, csv.Error) as e:
        raise ValueError(f"{p}: cannot read the study CSV ({e})") from None
    need = {"material", "step_deg", "n_slices", "repeats", "plan", "noise", "method", "status", "capture_time_s"}
    if not rows or not need <= set(rows[0]):
        missing = sorted(need - set(rows[0])) if rows else sorted(need)
        raise ValueError(f"{p}: not a study CSV (line 1: expected the columns {', '.join(missing)})")
    return [{k: v for k, v in r.items() if v not in ("", None)} for r in rows]


def merge_rows(rows: list[dict[str, Any]], earlier: Sequence[dict[str, Any]], ran: set[str], source: str
               ) -> tuple[list[dict[str, Any]], str]:
    """``rows`` of this run plus the ``earlier`` rows of every material not in ``ran``, and the sentence that says
    so ("" when none is kept)."""
    kept = [r for r in earlier if r["material"] not in ran]
    if not kept:
        return rows, ""
    mats = sorted({r["material"] for r in kept})
    methods = sorted({r["method"] for r in kept}, key=lambda m: METHODS.index(m) if m in METHODS else 99)
    note = (f"Rows of {', '.join(mats)} ({len(kept)} rows, methods {', '.join(methods)}) are taken from {source} "
            "(--merge)" + (f"; the rows of {', '.join(sorted(ran))} are computed by this command." if ran else "."))
    return rows + kept, note


def run_study(cases: Sequence[Case], base_config: str | Path, workdir: str | Path, out_dir: str | Path,
              name: str, command: str, scheduler: str | None = None, workers: int | None = None,
              progress: bool = True, catalogue: dict[str, dict[str, Any]] | None = None,
              metric: str = "rel_rmse_cos", merge: Sequence[dict[str, Any]] = (), merge_source: str = ""
              ) -> list[dict[str, Any]]:
    """Run ``cases`` through the executor, write ``out_dir/name.csv``, ``name-pareto.png`` and the ``name`` section
    of ``out_dir/study.md``; return rows.
    ``catalogue``: material dicts by name (default :data:`MATERIALS`); ``metric``: what the recommendations use;
    ``merge``: rows of an earlier run (:func:`read_rows` of ``merge_source``) kept for the materials this run
    does not capture (the markdown says which)."""
    catalogue = catalogue if catalogue is not None else MATERIALS
    from tqdm import tqdm

    from reconstruction.executor import make_executor, run_all

    base_config = Path(base_config).resolve()
    workdir = Path(workdir).resolve()
    out_dir = Path(out_dir)
    workdir.mkdir(parents=True, exist_ok=True)
    out_dir.mkdir(parents=True, exist_ok=True)
    rows: list[dict[str, Any]] = []
    bar = tqdm(total=len(cases), unit="capture", disable=not progress, desc="study")

    def done(case: Case, fut: Any) -> None:
        try:
            rows.extend(fut.result())
        except Exception as e:  # noqa: BLE001 - a crashed worker is reported as a failed case
            rows.extend({**asdict(case), "method": m, "status": "crashed", "error": f"{type(e).__name__}: {e}"}
                        for m in METHODS)
        bar.update(1)

    with make_executor(scheduler, workers) as ex:
        base_text = base_config.read_text(encoding="utf-8")
        run_all(ex, run_case, [(c, base_text, str(workdir), catalogue[c.material]) for c in cases], on_done=done)
    bar.close()
    order = {c.name: i for i, c in enumerate(cases)}
    rows.sort(key=lambda r: (order.get(Case(r["material"], float(r["step_deg"]), int(r["n_slices"]),
                                            int(r["repeats"]), r["plan"], r["noise"]).name, 0),
                             METHODS.index(r["method"])))
    rows, note = merge_rows(rows, merge, {c.material for c in cases}, merge_source)
    write_csv(out_dir / f"{name}.csv", rows)
    write_markdown(out_dir / STUDY_PAGE, rows, name, command, metric, note)
    write_plot(out_dir / f"{name}-pareto.png", rows, f"Error against capture time ({name})")
    os.sync()
    return rows
