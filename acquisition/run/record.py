"""The run record of a capture, ``DIR/capture.json``: typed, owned by :class:`RunRecord`, written atomically.

It holds the history of every run of the capture (``runs``: start, resume, samples, times, status), the plan and
its estimate, the unmeasurable points, the end-of-run dark drift, the totals over all runs and the auto-ranging
record (``auto_range``: the dark level per integration time and the setting of every ranged point, stored the
moment they are measured, so a resumed capture converts with the same darks and counts every point once). The
slice file is the checkpoint of the samples; this file is the record of how they were taken.
"""

from __future__ import annotations

import json
import logging
import math
import os
import signal
import time
from dataclasses import asdict, dataclass, field
from enum import Enum
from pathlib import Path
from typing import Any

from acquisition.calibration import Reading
from acquisition.devices.autorange import setting_key
from reconstruction.atomic import atomic_open

log = logging.getLogger("acquisition.record")

__all__ = ["RunRecord", "AutoRangeRecord", "CaptureResult", "Stop", "exit_status", "result_dict", "SIDECAR_NAME"]

SIDECAR_NAME = "capture.json"


class Stop(Enum):
    """Why a capture ended; :func:`exit_status` maps each to the exit status of ``gonio-capture``."""

    COMPLETE = "complete"
    INTERRUPTED = "interrupted"          # SIGINT / SIGTERM (``CaptureResult.signum``)
    HARDWARE_FAULT = "hardware fault"    # a latched fault: the arms are not parked
    BENCH_FAILURE = "bench failure"      # communication or a device refusing a command
    IO_FAULT = "io fault"                # an output file could not be written (a full disk)
    CONFIG_REFUSED = "config refused"    # the simulator refused its sections: nothing moved
    PLAN_ERROR = "plan error"            # the plan cannot be run as given
    SAMPLE_CHANGED = "sample changed"    # a resume re-measured the last points: another sample is on the bench
    UNEXPECTED = "unexpected error"      # a bug or an unforeseen reply: stopped safely, resumable


def exit_status(stop: Stop, signum: int | None = None) -> int:
    """The exit status of ``gonio-capture`` for a capture that ended with ``stop``: 0 complete; 1 a hardware or
    communication fault, a full disk or an unforeseen error (resumable); 2 a config or plan the capture refused
    (nothing moved), or a resume that found another sample on the bench; 128 + the signal number when interrupted
    (130 SIGINT, 143 SIGTERM). It belongs with the run record (:mod:`acquisition.cli` re-exports it)."""
    if stop is Stop.COMPLETE:
        return 0
    if stop is Stop.INTERRUPTED:
        return 128 + (signum or signal.SIGINT)
    if stop in (Stop.CONFIG_REFUSED, Stop.PLAN_ERROR, Stop.SAMPLE_CHANGED):
        return 2
    return 1


@dataclass
class CaptureResult:
    """Outcome of a capture. Times in seconds; ``bench_time_s`` is the bench clock (simulated time on the
    simulator) over this run; ``motion_s`` the part spent moving to points (command to in position).
    ``stop`` says why it ended, ``exit_code`` the exit status ``gonio-capture`` gives it."""

    out_dir: str
    slice_path: str
    status: str = "running"               # "complete" | "interrupted" | "failed"
    message: str = ""
    exit_code: int = 0
    samples_total: int = 0
    samples_new: int = 0
    points_planned: int = 0
    unmeasurable: list[list[Any]] = field(default_factory=list)
    bench_time_s: float = 0.0
    bench_clock: str = "wall"             # "controller" when the bench reported its own clock
    motion_s: float = 0.0
    settle_s: float = 0.0
    read_s: float = 0.0
    wall_s: float = 0.0
    wall_per_sample_s: float = 0.0
    plan_motion_estimate_s: float = 0.0
    naive_motion_estimate_s: float = 0.0
    estimate_s: float = 0.0               # the time model's estimate of this run before refinement (bench s)
    estimate_refinement_s: float = 0.0    # its estimates of the refinement rounds, as they were planned
    estimate: dict[str, float] = field(default_factory=dict)  # its parts (acquisition.run.dryrun.estimate)
    dark_drift: list[float] | None = None
    adaptive_rounds: int = 0
    auto_ranged: int = 0                  # points of the capture (all runs) read at a shorter integration time
    auto_ranged_new: int = 0              # of them, the points this run measured
    auto_range_settings: dict[str, int] = field(default_factory=dict)  # integration time (s) -> points
    auto_range_readings: int = 0          # readings discarded by auto-ranging in this run
    auto_range_overhead_s: float = 0.0    # their integration time plus new dark readings, this run (s)
    sample_check: dict[str, Any] | None = None  # a resume's last recorded points measured again (plans.check_sample)

    def __post_init__(self) -> None:
        self.stop: Stop | None = None
        self.signum: int | None = None

    @property
    def ok(self) -> bool:
        return self.status == "complete"

    def end(self, stop: Stop, message: str, signum: int | None = None) -> None:
        """The capture ended with ``stop``: status, message and exit status follow."""
        self.stop, self.signum, self.message = stop, signum, message
        self.status = {Stop.COMPLETE: "complete", Stop.INTERRUPTED: "interrupted"}.get(stop, "failed")
        self.exit_code = exit_status(stop, signum)

    def raise_for_status(self) -> None:
        if not self.ok:
            from acquisition.errors import AcquisitionError

            raise AcquisitionError(self.message)


def result_dict(r: CaptureResult) -> dict[str, Any]:
    """The result as a JSON-able dict."""
    d = asdict(r)
    for k, v in d.items():
        if isinstance(v, float) and not math.isfinite(v):
            d[k] = None
    return d


def _parse_point(key: str) -> tuple[float, float]:
    """``"30.0,29.5"`` (a key of ``auto_range.points``) -> (30.0, 29.5)."""
    a, b = key.split(",")
    return (float(a), float(b))


@dataclass
class AutoRangeRecord:
    """``auto_range`` of the run record: the darks per setting (key :func:`~acquisition.devices.autorange.setting_key`)
    and the integration time of every ranged point (key ``"theta_i,theta_o"`` with repr floats)."""

    darks: dict[str, dict[str, Any]] = field(default_factory=dict)
    points: dict[str, float] = field(default_factory=dict)
    enabled: bool = True
    reference_integration_time_s: float = 0.0
    min_integration_time_s: float = 0.0
    ladder_s: list[float] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)  # other keys (white_reference_..., overhead_s)
    point_gains: dict[str, float] = field(default_factory=dict)  # the gain of every ranged point (with gains)
    ladder_gains: list[float] | None = None

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> AutoRangeRecord:
        d = dict(d)
        known = {k: d.pop(k) for k in ("darks", "points", "enabled", "reference_integration_time_s",
                                       "min_integration_time_s", "ladder_s", "point_gains", "ladder_gains")
                 if k in d}
        d.pop("settings", None)
        d.pop("ranged_points", None)
        return cls(**known, extra=d)

    def to_json(self) -> dict[str, Any]:
        return {**self.extra, "darks": self.darks, "points": self.points, "enabled": self.enabled,
                "reference_integration_time_s": self.reference_integration_time_s,
                "min_integration_time_s": self.min_integration_time_s, "ladder_s": self.ladder_s,
                "settings": self.settings(), "ranged_points": len(self.points),
                **({"point_gains": self.point_gains, "ladder_gains": self.ladder_gains}
                   if self.ladder_gains is not None else {})}

    def settings(self) -> dict[str, int]:
        """Setting (key: integration time, and gain when switched) -> ranged points, most sensitive first."""
        counts: dict[str, int] = {}
        sens: dict[str, float] = {}
        for k, t in self.points.items():
            g = self.point_gains.get(k)
            key = setting_key(t, g)
            counts[key] = counts.get(key, 0) + 1
            sens[key] = t * (1.0 if g is None else g)
        return dict(sorted(counts.items(), key=lambda kv: -sens[kv[0]]))

    def store_dark(self, t: float, rd: Reading, gain: float | None = None) -> None:
        self.darks[setting_key(t, gain)] = {"integration_time_s": t, **({"gain": gain} if gain is not None else {}),
                                            **rd.to_meta()}

    def dark_readings(self) -> dict[str, Reading]:
        return {k: Reading.from_meta(m) for k, m in self.darks.items()}

    def set_point(self, ti: float, to: float, t: float | None, gain: float | None = None) -> bool:
        """Record the setting of a point (``t`` None: read at the reference); True if the record changed."""
        key = f"{ti!r},{to!r}"
        if t is not None:
            self.points[key] = t
            if gain is not None:
                self.point_gains[key] = gain
            return True
        self.point_gains.pop(key, None)
        if key in self.points:
            del self.points[key]
            return True
        return False

    def prune(self, done: set[tuple[float, float]], key_of: Any) -> None:
        """Drop points that never reached the slice (killed between record and append)."""
        for k in [k for k in self.points if key_of(_parse_point(k)) not in done]:
            del self.points[k]
            self.point_gains.pop(k, None)


@dataclass
class RunRecord:
    """``DIR/capture.json``. ``runs`` are this capture's runs (dicts of the keys the module docstring names);
    :meth:`save` writes it atomically."""

    path: Path
    runs: list[dict[str, Any]] = field(default_factory=list)
    status: str | None = None
    auto_range: AutoRangeRecord | None = None
    dark_drift: list[float] | None = None
    plan_fields: dict[str, Any] = field(default_factory=dict)  # config, plan, fingerprint, estimate, ...
    extra: dict[str, Any] = field(default_factory=dict)  # keys of other versions, kept as they were

    @classmethod
    def load(cls, path: Path) -> RunRecord:
        """The record at ``path`` (an empty one if there is none; an unreadable one is logged and replaced)."""
        rec = cls(Path(path))
        if not rec.path.exists():
            return rec
        try:
            d = json.loads(rec.path.read_text(encoding="utf-8"))
            if not isinstance(d, dict):
                raise ValueError("not a JSON object")
        except (OSError, ValueError) as e:
            log.warning("%s unreadable (%s); starting a new run record", rec.path, e)
            return rec
        rec.runs = list(d.pop("runs", []) or [])
        rec.status = d.pop("status", None)
        ar = d.pop("auto_range", None)
        rec.auto_range = AutoRangeRecord.from_json(ar) if isinstance(ar, dict) else None
        rec.dark_drift = d.pop("dark_drift", None)
        d.pop("totals", None)
        for k in ("config", "plan", "plan_fingerprint", "points_planned", "unmeasurable", "estimate"):
            if k in d:
                rec.plan_fields[k] = d.pop(k)
        rec.extra = d
        return rec

    def forget_all_but_runs(self) -> None:
        """A new capture in the folder: only the history of runs is kept."""
        self.status, self.auto_range, self.dark_drift = None, None, None
        self.plan_fields, self.extra = {}, {}

    @property
    def attempt(self) -> int:
        """How many runs came before the present one."""
        return max(len(self.runs) - 1, 0)

    def previous_bench_time(self) -> float:
        return float(sum(run.get("bench_time_s", 0.0) for run in self.runs[:-1]))

    def start_run(self, plan_fields: dict[str, Any], resume: bool, samples_before: int) -> None:
        self.plan_fields = plan_fields
        self.status = "running"
        self.runs.append({"started_unix": time.time(), "resume": resume, "samples_before": samples_before,
                          "pid": os.getpid()})
        self.save()

    def finish_run(self, r: CaptureResult) -> None:
        run = self.runs[-1]
        run.update({"ended_unix": time.time(), "status": r.status, "message": r.message,
                    "samples_new": r.samples_new, "samples_total": r.samples_total, "bench_time_s": r.bench_time_s,
                    "bench_clock": r.bench_clock, "motion_s": r.motion_s, "settle_s": r.settle_s,
                    "read_s": r.read_s, "wall_s": r.wall_s, "wall_per_sample_s": r.wall_per_sample_s,
                    "calibration_s": max(r.bench_time_s - r.motion_s - r.settle_s - r.read_s, 0.0),
                    "estimate_s": r.estimate_s + r.estimate_refinement_s})
        self.status = r.status
        if self.auto_range is not None:
            run["auto_range"] = {"readings_discarded": r.auto_range_readings, "overhead_s": r.auto_range_overhead_s}
            self.auto_range.extra["overhead_s"] = float(sum(x.get("auto_range", {}).get("overhead_s", 0.0)
                                                            for x in self.runs))
        if r.sample_check is not None:
            run["sample_check"] = r.sample_check
        if r.dark_drift is not None:
            self.dark_drift = r.dark_drift
        try:
            self.save()
        except OSError as e:  # pragma: no cover
            log.error("cannot write %s: %s", self.path, e)

    def to_json(self) -> dict[str, Any]:
        d: dict[str, Any] = {**self.extra, **self.plan_fields, "runs": self.runs}
        if self.status is not None:
            d["status"] = self.status
        if self.auto_range is not None:
            d["auto_range"] = self.auto_range.to_json()
        if self.dark_drift is not None:
            d["dark_drift"] = self.dark_drift
        if any("ended_unix" in r for r in self.runs):
            d["totals"] = {k: float(sum(x.get(k, 0.0) for x in self.runs))
                           for k in ("bench_time_s", "motion_s", "settle_s", "read_s", "calibration_s", "wall_s")}
        return d

    def save(self, durable: bool = True) -> None:
        """Write the record atomically (raises OSError: a full disk). ``durable`` False: without the fsync (a
        point's auto-ranged setting, saved before every sample: atomic against a kill, and a power cut loses at
        most the settings of the last points, which the record only reports)."""
        if durable:
            with atomic_open(self.path, "w", encoding="utf-8") as fh:
                json.dump(self.to_json(), fh, indent=1, sort_keys=True)
                fh.write("\n")
            return
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            tmp.write_text(json.dumps(self.to_json(), indent=1, sort_keys=True) + "\n", encoding="utf-8")
            os.replace(tmp, self.path)
        except OSError as e:
            tmp.unlink(missing_ok=True)
            e.filename = str(self.path)
            raise
