"""The hostile campaign's corpus of issue 49: silent wrong answers and the messages a user meets, as
:class:`tests.hostile.Case` runs of ``gonio-capture`` and ``gonio-reconstruct`` (subprocesses, judged like the rest
of the campaign: exit status, one line for a refusal, no traceback, and here also what the message must and must
not say and which files a refused run must leave as they were).

* resumes of a small capture whose folder was tampered with: a row moved off the plan, a value impossibly below
  zero, a flipped digit (``slice.crc``), the slice deleted or emptied while ``capture.json`` records samples (all
  refused, nothing changed), a torn last line (one logged line, no Python warning), ``--force`` (the rows set aside,
  the capture completed);
* ``--check`` of the PM100 bench where pyvisa has no VISA library underneath (named; exit 0 on a machine with one);
* reconstructions the samples cannot support: three samples through fit, revolve, bivariate and auto (a warning,
  in every case), three samples around the mirror direction (auto's refusal names each method's reason, never
  ``None``), a value 7000 standard deviations below zero (named).
"""

from __future__ import annotations

import shutil
import sys
from pathlib import Path

import numpy as np

from tests.hostile import REPO, Case

#: the small capture the resume cases tamper with: two incidences, 28 samples, a second or two of wall time
PLAN = {"plan": {"theta_i_deg": [30.0, 50.0], "theta_o_step_deg": 10.0}}


def _base_capture(work: Path) -> tuple[Path, Path]:
    """(config, capture folder) of a complete small capture on the simulated bench, made once per corpus."""
    import subprocess

    from tests.test_acq_support import make_raw, write_config

    cfg = write_config(work / "small.toml", make_raw(PLAN))
    base = work / "base"
    if not (base / "capture.json").exists():
        r = subprocess.run([sys.executable, "-m", "acquisition.cli", "--config", str(cfg), "--out", str(base)],
                           cwd=REPO, capture_output=True, text=True, timeout=300)
        if r.returncode != 0:
            raise RuntimeError(f"the corpus's base capture failed: {r.stderr[-500:]}")
    return cfg, base


def _folder(base: Path, to: Path, edit=None, files=("slice.csv", "capture.json", "slice.crc")) -> Path:
    shutil.rmtree(to, ignore_errors=True)
    to.mkdir(parents=True)
    for name in files:
        shutil.copyfile(base / name, to / name)
    if edit is not None:
        p = to / "slice.csv"
        p.write_text(edit(p.read_text()))
    return to


def _row(text: str, start: str, new_cells=None, whole=None) -> str:
    lines = text.split("\n")
    k = next(i for i, ln in enumerate(lines) if ln.startswith(start))
    cells = lines[k].split(",")
    lines[k] = whole(cells) if whole is not None else ",".join(new_cells(cells))
    return "\n".join(lines)


def _flip(cells: list[str]) -> list[str]:
    v = cells[2]
    return [*cells[:2], v[:4] + str((int(v[4]) + 1) % 10) + v[5:], *cells[3:]]


def capture_cases(work: Path) -> list[Case]:
    """Resumes of tampered capture folders, and ``--check`` of the PM100 bench."""
    work.mkdir(parents=True, exist_ok=True)
    cfg, base = _base_capture(work)

    def resume(name: str, out: Path, *, force: bool = False, **kw) -> Case:
        argv = ["--config", str(cfg), "--out", str(out), "--resume", *(["--force"] if force else [])]
        return Case(f"resume: {name}", "capture", argv, **kw)

    cases = []
    refused = {
        "a row off the plan (theta_i 30 -> 70)": (lambda t: _row(t, "30.0,50.0,", lambda c: ["70.0", *c[1:]]),
                                                  "(70, 50): not a point of the plan", ("slice.csv", "capture.json")),
        "f_r -0.5 +- 7e-5": (lambda t: _row(t, "30.0,50.0,", lambda c: [*c[:2], "-0.5", "7e-05", *c[4:]]),
                             "standard deviations below zero", ("slice.csv", "capture.json")),
        "a flipped digit": (lambda t: _row(t, "30.0,50.0,", _flip), "edited or corrupted since it was written",
                            ("slice.csv", "capture.json", "slice.crc")),
    }
    for k, (name, (edit, says, files)) in enumerate(refused.items()):
        out = _folder(base, work / f"refused-{k}", edit, files)
        cases.append(resume(name, out, ok=False, expect=[says, "--force"], unchanged=[out / "slice.csv"]))
    out = _folder(base, work / "deleted", files=("capture.json",))
    cases.append(resume("slice.csv deleted, capture.json kept", out, ok=False, expect=["records 28 sample(s)"],
                        unchanged=[out / "capture.json"]))
    out = _folder(base, work / "emptied", files=("capture.json",))
    (out / "slice.csv").write_text("")
    cases.append(resume("slice.csv emptied, capture.json kept", out, ok=False, expect=["records 28 sample(s)"],
                        unchanged=[out / "slice.csv", out / "capture.json"]))
    out = _folder(base, work / "torn", lambda t: t.rstrip("\n")[:-12])
    cases.append(resume("a torn last line", out, ok=True, says=["torn last line"],
                        never=["UserWarning", "warnings.warn"]))
    out = _folder(base, work / "forced", lambda t: _row(t, "30.0,50.0,", _flip))
    cases.append(resume("--force sets a flipped row aside", out, force=True, ok=True, says=["captured 1 new"],
                        outputs=[out / "slice.csv"]))
    cases.append(Case("--check: a PM100 bench, pyvisa without a VISA library", "capture",
                      ["--config", str(REPO / "configs" / "pm100-bench.toml"), "--check"],
                      expect=["pyvisa has no VISA library to use"]))
    return cases


def reconstruct_cases(work: Path) -> list[Case]:
    """Reconstructions from samples that cannot support a table, and values impossible for their std."""
    from reconstruction.core.models import Material
    from reconstruction.core.slicedata import Slice
    from reconstruction.formats.slicefile import write_slice
    from reconstruction.synthetic import synthetic_slice

    work.mkdir(parents=True, exist_ok=True)
    mat = Material.from_dict({"name": "grey", "lobes": [{"type": "lambert", "albedo": 0.3},
                                                        {"type": "ggx", "alpha": 0.2, "specular": 0.3}]})

    def write(name: str, s: Slice, std=None) -> Path:
        p = work / name
        n = len(s)
        write_slice(p, Slice(s.theta_i_deg, s.theta_o_deg, s.values, s.channels,
                             0.01 * np.abs(s.values) + 1e-6 if std is None else std, np.full(n, 4),
                             1.7e9 + np.arange(n)))
        return p

    one = synthetic_slice(mat, (30.0,), step_deg=5.0)
    three = write("three.csv", one.take(np.isin(one.theta_o_deg, [-70.0, -40.0, 0.0])))
    mirror = write("mirror.csv", synthetic_slice(mat, (30.0,), step_deg=1.0).take(
        np.isin(synthetic_slice(mat, (30.0,), step_deg=1.0).theta_o_deg, [29.0, 30.0, 31.0])))
    wide = synthetic_slice(mat, (20.0, 40.0, 60.0), step_deg=5.0)
    std = 0.01 * np.abs(wide.values) + 1e-6
    k = int(np.flatnonzero((wide.theta_i_deg == 40.0) & (wide.theta_o_deg == 10.0))[0])
    wide.values[k], std[k] = -0.5, 7e-5
    negative = write("negative.csv", wide, std)
    cases = []
    def own(name: str) -> Path:  # each case its own folder: a neighbour's table being written is not a leftover
        d = work / name
        d.mkdir(exist_ok=True)
        return d / f"{name}.binary"

    for method in ("fit", "revolve", "bivariate", "auto"):
        out = own(f"three-{method}")
        cases.append(Case(f"3 samples, --method {method}", "reconstruct",
                          [str(three), "--method", method, "--out", str(out)], [out], ok=True,
                          says=["too few to support", "checks passed, but see the"]))
    out = own("mirror")
    cases.append(Case("3 samples at the mirror, auto's refusal", "reconstruct",
                      [str(mirror), "--method", "auto", "--out", str(out)], [out], ok=False,
                      expect=["no sample could be held out to judge it"], never=["None"]))
    out = own("negative")
    cases.append(Case("f_r -0.5 +- 7e-5 among good samples", "reconstruct",
                      [str(negative), "--method", "fit", "--out", str(out)], [out], ok=True,
                      says=["(40, 10) f_r -0.5 +- 7e-05 (7143 sigma)"]))
    return cases
