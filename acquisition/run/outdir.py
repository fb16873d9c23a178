"""The output folder of a capture: created, checked writable before anything moves, and what a resume may
continue (the same experiment: plan, fingerprint of the settings that give a sample its meaning, calibration
mode, detector and integration time), all raising :class:`~acquisition.errors.PlanError` before any motion.
"""

from __future__ import annotations

import logging
import math
import os
import tempfile
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from acquisition.config import BenchConfig
from acquisition.errors import PlanError
from acquisition.plans.plan import Plan
from acquisition.run.fingerprint import describe_differences, differences
from acquisition.run.record import RunRecord
from acquisition.run.rowcheck import SET_ASIDE_NAME, RowProblem, describe_problems, row_problems, set_aside
from reconstruction.core.slicedata import Slice, SliceError
from reconstruction.formats.slicefile import read_slice

log = logging.getLogger("acquisition.outdir")

__all__ = ["SLICE_NAME", "LOG_NAME", "SIM_LOG_NAME", "out_dir_problem", "make_out_dir", "check_writable",
           "has_rows", "Resume", "check_resume", "recorded_samples"]

SLICE_NAME = "slice.csv"
LOG_NAME = "capture.log"
SIM_LOG_NAME = "simulator.log"


def out_dir_problem(out: Path, err: OSError | None = None) -> str:
    """Why ``out`` cannot be the output directory: one line naming it (``err``: what creating it raised)."""
    for p in (out, *out.parents):
        if p.exists() and not p.is_dir():
            return f"{out}: is a file, not a directory" if p == out else f"{out}: {p} is a file, not a directory"
    why = (err.strerror or str(err)) if err is not None else "cannot be created"
    return f"{out}: cannot create the output directory: {why}"


def make_out_dir(out: Path) -> None:
    """Create the output directory; a path that is a file or cannot be created is a :class:`PlanError`."""
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise PlanError(out_dir_problem(out, e)) from None


def check_writable(out: Path) -> None:
    """Everything a run writes must be writable, checked before anything moves: the folder (run record, new
    files), and the slice, log and simulator log it appends to."""
    try:
        fd, tmp = tempfile.mkstemp(prefix=".write-test.", dir=out)
        os.close(fd)
        os.unlink(tmp)
    except OSError as e:
        raise PlanError(f"--out {out}: cannot write in the output folder ({e.strerror or e})") from None
    for p in (out / SLICE_NAME, out / LOG_NAME, out / SIM_LOG_NAME):
        if not p.exists():
            continue
        try:
            os.close(os.open(p, os.O_WRONLY | os.O_APPEND))
        except OSError as e:
            raise PlanError(f"--out {out}: {p.name} cannot be written ({e.strerror or e}); a capture "
                            "appends to it") from None


def has_rows(path: Path) -> bool:
    """True if the slice file has its column header and at least one complete (newline-terminated) data row."""
    with open(path, "rb") as fh:
        data = fh.read()
    lines = data.replace(b"\r\n", b"\n").replace(b"\r", b"\n").split(b"\n")  # any line ending
    complete = lines[:-1]  # the last element is "" or a torn line
    body = [ln for ln in complete if ln and not ln.startswith(b"#")]
    return len(body) >= 2  # column header + one row


@dataclass
class Resume:
    """What a run continues: the slice already in the folder (None: a new capture), the harmless setting changes
    since it was started, and whether it predates configuration fingerprints."""

    existing: Slice | None = None
    setting_changes: list[tuple[str, Any, Any]] = field(default_factory=list)
    legacy: bool = False
    sample_changes: list[tuple[str, Any, Any]] = field(default_factory=list)  # [material], accepted with --force
    set_aside: tuple[list[RowProblem], Path] | None = None  # rows moved out of the slice, as --force asks
    notes: list[str] = field(default_factory=list)  # what reading the slice warned of (a torn last line)

    def log_checks(self, slice_path: Path) -> None:
        for note in self.notes:
            log.warning("resume: %s; it is cut off before appending", note)
        if self.set_aside is not None:
            probs, aside = self.set_aside
            log.warning("resume: set aside %d row(s) of %s in %s, as --force asks: %s", len(probs), slice_path, aside,
                        describe_problems(slice_path, probs))
        if self.sample_changes:
            log.warning("resuming with another [material] (the simulated sample), as --force asks: %s",
                        describe_differences(self.sample_changes))
        if self.setting_changes:
            log.info("resuming with changed setting(s) that cannot change a sample: %s",
                     describe_differences(self.setting_changes))
        if self.legacy:
            log.info("%s has no configuration fingerprint (an older capture): only the plan, calibration mode, "
                     "detector type and integration time were checked", slice_path)


def _check_fingerprint(res: Resume, meta: dict[str, Any], slice_path: Path, fp: dict[str, Any],
                       settings: dict[str, Any], force: bool = False) -> None:
    """Refuse a resume whose config changes the meaning of a sample (``force``: but for the [material], the
    simulated sample, which a deliberate change may swap); remember the harmless changes."""
    old = meta.get("config_fingerprint")
    if not isinstance(old, dict):
        res.legacy = True
        return
    diffs = differences(old, fp)
    if force:
        res.sample_changes = [d for d in diffs if d[0].startswith("[material]")]
        diffs = [d for d in diffs if not d[0].startswith("[material]")]
    if diffs:
        plan = [d for d in diffs if d[0].startswith(("[plan", "plan "))]
        what = ("plan" if len(plan) == len(diffs) else "plan and configuration" if plan else "configuration")
        raise PlanError(f"cannot resume: {slice_path} was captured with a different {what}: "
                        f"{describe_differences(diffs)}; restore {'it' if len(diffs) == 1 else 'them'} or "
                        "choose another --out")
    old_settings = meta.get("config_settings")
    if isinstance(old_settings, dict):
        res.setting_changes = differences(old_settings, settings)


def recorded_samples(record: RunRecord) -> int:
    """How many samples the run record says the slice held: the most any run ended with or started from."""
    counts = [run.get(k, 0) for run in record.runs for k in ("samples_total", "samples_before")]
    return max((int(c) for c in counts if isinstance(c, (int, float)) and not isinstance(c, bool)), default=0)


def _refuse_lost_slice(slice_path: Path, record: RunRecord) -> None:
    """A resume whose slice is missing or holds no sample while the run record names captured samples: the slice
    was deleted or emptied; starting over would hide that, so it is a :class:`PlanError` naming what was captured."""
    n = recorded_samples(record)
    if n <= 0:
        return
    last = next((run for run in reversed(record.runs) if "ended_unix" in run), record.runs[-1])
    when = time.strftime("%Y-%m-%d %H:%M", time.localtime(float(last.get("ended_unix", last.get("started_unix", 0)))))
    state = "is missing" if not slice_path.exists() else "holds no sample"
    raise PlanError(f"cannot resume: {slice_path} {state}, but {record.path} records {n} sample(s) captured "
                    f"({len(record.runs)} run(s), the last {last.get('status', 'unfinished')} at {when}); restore "
                    "the slice file, or choose another --out to start a new capture")


def check_resume(cfg: BenchConfig, plan: Plan, out: Path, resume: bool, record: RunRecord, fp: dict[str, Any],
                 settings: dict[str, Any], force: bool = False, measurable: list[Any] | None = None,
                 geometry: Any = None) -> Resume:
    """What the run in ``out`` continues, or a :class:`PlanError` if it may not (another experiment, or a capture
    there without ``--resume``, or rows on disk that are not points of the plan or whose values are impossible:
    :mod:`acquisition.run.rowcheck`, given the plan's ``measurable`` points; ``force`` sets them aside). A slice
    without a complete sample is removed (nothing to keep) unless the run record names captured samples (then a
    resume refuses); the record of a folder without a slice keeps its history of runs only."""
    slice_path = out / SLICE_NAME
    res = Resume()
    if resume and not (slice_path.exists() and has_rows(slice_path)):
        _refuse_lost_slice(slice_path, record)
    if slice_path.exists() and not has_rows(slice_path):
        # killed before the first sample was complete: nothing to keep (the calibration is re-measured)
        log.info("%s holds no complete sample; starting it again", slice_path)
        slice_path.unlink()
    if not slice_path.exists():
        if resume:
            log.info("nothing to resume in %s: starting a new capture", out)
        record.forget_all_but_runs()
        return res
    if not resume:
        raise PlanError(f"{out} already holds a capture ({slice_path}); continue it with --resume, "
                        "or choose another --out")
    existing = _read_quietly(slice_path, res.notes)
    meta = existing.meta
    _check_fingerprint(res, meta, slice_path, fp, settings, force)
    fpr = meta.get("plan_fingerprint")
    if fpr != plan.fingerprint():
        raise PlanError(f"cannot resume: {slice_path} was captured with a different plan (fingerprint "
                        f"{fpr}, the config now gives {plan.fingerprint()}); restore the plan or choose "
                        "another --out")
    kind = existing.kind
    if (cfg.detector.type in ("photodiode", "pm100")) != (kind == "grey"):
        raise PlanError(f"cannot resume: {slice_path} has value columns {existing.channels[:4]}, but a "
                        f"{cfg.detector.type} gives {'one value column' if kind != 'grey' else 'spectra'}")
    cal = meta.get("calibration", {})
    if cal.get("mode") != cfg.calibration.mode:
        raise PlanError(f"cannot resume: {slice_path} used {cal.get('mode')!r} calibration, the config "
                        f"says {cfg.calibration.mode!r}")
    if meta.get("detector", {}).get("type") != cfg.detector.type:
        raise PlanError(f"cannot resume: {slice_path} was captured with a "
                        f"{meta.get('detector', {}).get('type')}, the config has a {cfg.detector.type}")
    t_was = meta.get("detector", {}).get("integration_time_s")
    t_now = cfg.detector.integration_time_s
    if t_was is not None and not math.isclose(float(t_was), t_now, rel_tol=1e-9):
        raise PlanError(f"cannot resume: {slice_path} was calibrated at [detector].integration_time_s = "
                        f"{float(t_was):g} s, the config now says {t_now:g} s; restore it or choose another --out")
    if measurable is not None:
        probs = row_problems(existing, measurable, cfg.motion.tolerance_deg, plan.adaptive is not None, geometry,
                             slice_path)
        if probs and not force:
            raise PlanError(f"cannot resume: {len(probs)} row(s) on disk cannot be continued from: "
                            f"{describe_problems(slice_path, probs, 3)}; restore them, or set them aside with "
                            f"--resume --force (they move to {SET_ASIDE_NAME})")
        if probs:
            res.set_aside = (probs, set_aside(slice_path, probs))
            existing = _read_quietly(slice_path)
    res.existing = existing
    return res


def _read_quietly(slice_path: Path, notes: list[str] | None = None) -> Slice:
    """The slice being resumed; what the reader warned of (a torn last line) goes to ``notes``, which the resume
    logs in one line each, not a Python warning on the console."""
    try:
        with warnings.catch_warnings(record=True) as seen:
            warnings.simplefilter("always")
            s = read_slice(slice_path)
    except SliceError as e:
        raise PlanError(f"cannot resume: {e}") from None
    if notes is not None:
        notes.extend(str(w.message) for w in seen)
    return s
