"""Where a capture's samples go: ``slice.csv`` (:class:`SliceOutput`, the engine's sink) and the check value of
each of its rows, ``slice.crc`` (:class:`RowChecks`).

``slice.crc`` holds one line per row appended, ``theta_i,theta_o,crc``: the row's angles and the CRC-32
(``zlib.crc32``, 8 hex digits) of its numbers (:func:`row_check`: independent of column order, line endings and
number formatting, so another tool's harmless rewrite of the slice keeps them valid). A resume
(:mod:`acquisition.run.rowcheck`) recomputes it for every row on disk: a row edited or corrupted since it was
written (a flipped digit) no longer matches, and a row the capture never wrote has no entry. The newest entry of a
point counts (a point set aside and measured again). The file is flushed with each row but not fsynced: a power
cut may lose its last entries, and a row without an entry is only refused when the file holds entries for rows
after it. A slice without it (older software) is checked from its next resume on, its rows as they are then.
Other readers of the slice never need it.
"""

from __future__ import annotations

import logging
import time
import zlib
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from acquisition.calibration import Calibration
from acquisition.optics import footprint_meta, instrument_of
from acquisition.run.progress import ProgressFile
from reconstruction.formats.slicefile import SliceWriter

log = logging.getLogger("acquisition.engine")

__all__ = ["SliceOutput", "RowChecks", "ROWCHECK_NAME", "row_check", "read_row_checks"]

ROWCHECK_NAME = "slice.crc"
_HEADER = "# gonio-brdf row checks: theta_i_deg,theta_o_deg,crc32 of the row's numbers (acquisition.run.sliceout)\n"


_FIXED = ("theta_i_deg", "theta_o_deg", "repeats", "unix_time_s")


def row_check(line: str, columns: Sequence[str]) -> tuple[str, str, str]:
    """(theta_i, theta_o, crc) of a slice row: the angles as ``repr`` of their floats, and the CRC-32 (8 lower-case
    hex digits) of the row's numbers in the format's own column order (theta_i, theta_o, the values, their
    standard deviations, repeats, unix_time_s), each as ``repr`` of its float, joined by commas: independent of the
    file's column order, line endings and number formatting (a tool that reorders columns or writes ``30`` for
    ``30.0`` changes nothing), changed by any number that changes. Raises ValueError for a row that is not
    numbers in ``columns``."""
    cells = dict(zip(columns, line.rstrip("\r\n").split(","), strict=True))
    channels = [c for c in columns if c not in _FIXED and not c.endswith("_std")]
    order = ["theta_i_deg", "theta_o_deg", *channels, *(f"{c}_std" for c in channels), "repeats", "unix_time_s"]
    nums = [repr(float(cells[c])) for c in order]
    return nums[0], nums[1], f"{zlib.crc32(','.join(nums).encode('ascii')):08x}"


def read_row_checks(path: Path) -> dict[tuple[str, str], str] | None:
    """``slice.crc`` beside ``path`` (the slice): (theta_i cell, theta_o cell) -> crc (the newest entry), or None
    when there is none."""
    side = path.with_name(ROWCHECK_NAME)
    try:
        text = side.read_text(encoding="utf-8", errors="replace")
    except FileNotFoundError:
        return None
    out: dict[tuple[str, str], str] = {}
    for ln in text.splitlines():
        parts = ln.split(",")
        if len(parts) == 3 and not ln.startswith("#"):
            out[(parts[0], parts[1])] = parts[2]
    return out


class RowChecks:
    """Appends the check value of every row written to ``slice.crc`` (module docstring)."""

    def __init__(self, path: Path, columns: Sequence[str]) -> None:
        self.path = path
        self.columns = list(columns)
        self._fh = open(path, "a", encoding="utf-8", newline="\n")

    @classmethod
    def open(cls, slice_path: Path, columns: Sequence[str], new: bool = False) -> RowChecks | None:
        """The check file of ``slice_path`` (``new``: a new capture, started afresh). A resumed slice without one
        gets one holding its present rows (they passed the resume's checks); one with it gets the values of the
        rows after its last checked one: a capture killed between a row's append and its check value's (the row
        is the capture's, fsynced; left out, the rows this run appends would make it look foreign). None if it
        cannot be written (the capture goes on without it; the slice is what counts)."""
        side = slice_path.with_name(ROWCHECK_NAME)
        try:
            if new or not side.exists():
                side.write_text(_HEADER, encoding="utf-8")
            if not new:
                rows = [ln for ln in slice_path.read_text(encoding="utf-8-sig").splitlines(keepends=True)
                        if ln[:1] not in ("#", "") and ln.endswith(("\n", "\r"))][1:]  # after the header
                values = [row_check(ln, columns) for ln in rows]
                have = read_row_checks(slice_path) or {}
                k = len(values)
                while k > 0 and (values[k - 1][0], values[k - 1][1]) not in have:  # at most the rows of one kill
                    k -= 1
                if k < len(values):
                    with open(side, "a", encoding="utf-8", newline="\n") as fh:
                        fh.writelines(",".join(v) + "\n" for v in values[k:])
            return cls(side, columns)
        except (OSError, ValueError, IndexError) as e:
            log.warning("cannot keep the row checks in %s (%s); the capture goes on without them", side, e)
            return None

    def add(self, line: str) -> None:
        try:
            self._fh.write(",".join(row_check(line, self.columns)) + "\n")
            self._fh.flush()
        except OSError as e:  # the slice row is safe; only its check value is lost
            log.warning("cannot write %s: %s", self.path, e)

    def close(self) -> None:
        try:
            self._fh.close()
        except OSError:
            pass


def _software_version() -> str:
    try:
        from importlib.metadata import version

        return version("gonio-brdf")
    except Exception:  # pragma: no cover
        return "unknown"




class SliceOutput:
    """The engine's sink: ``slice.csv``, created with its metadata once the calibration is known (a resume
    appends to the existing file), and the check value of every row in ``slice.crc`` (:class:`RowChecks`)."""

    def __init__(self, eng: Any, resume: bool, watch: ProgressFile | None = None) -> None:
        self.eng = eng  # the RunEngine
        self.resume = resume
        self.watch = watch
        self.writer: SliceWriter | None = None
        self.checks: RowChecks | None = None

    def open(self, cal: Calibration, reference_integration_time_s: float | None) -> None:
        eng = self.eng
        det = eng.bench.detector
        if self.resume:
            self.writer = SliceWriter(eng.slice_path, det.channels)
            self.checks = RowChecks.open(eng.slice_path, self.writer.columns)
            return
        cfg, c = eng.cfg, eng.cfg.calibration
        meta = {
            "bench": str(cfg.path),
            "bench_name": cfg.bench.name,
            "transport": cfg.bench.transport,
            "software_version": _software_version(),
            "quantity": "brdf",
            "calibration": {**c.to_meta(), **cal.to_meta()},
            "detector": {"type": det.type, "integration_time_s": cfg.detector.integration_time_s,
                         "saturation": det.saturation, "auto_range": cfg.detector.auto_range,
                         **({} if cfg.detector.on_board else {"device": det.describe()})},
            "instrument": instrument_of(cfg).to_meta(),
            "plan": eng.plan.to_meta(),
            "plan_fingerprint": eng.plan.fingerprint(),
            "config_fingerprint": eng.fingerprint,
            "config_settings": eng.settings,
            "unmeasurable": eng.result.unmeasurable,
            "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
        }
        if cfg.detector.gains:
            meta["detector"]["gains"] = list(cfg.detector.gains)
        fp = footprint_meta(cfg, [p[0] for p in eng.plan_points()])
        if fp is not None:
            meta["calibration"]["footprint"] = fp
        if cfg.detector.auto_range:
            meta["detector"]["min_integration_time_s"] = cfg.detector.min_integration_time_s
            if c.mode == "relative" and reference_integration_time_s is not None:
                meta["calibration"]["reference_reading_integration_time_s"] = reference_integration_time_s
        if cfg.sample_name:
            meta["material"] = cfg.sample_name
        self.writer = SliceWriter(eng.slice_path, det.channels, meta)
        self.checks = RowChecks.open(eng.slice_path, self.writer.columns, new=True)

    def append(self, ti: float, to: float, f: list[float], std: list[float], repeats: int) -> None:
        assert self.writer is not None
        line = self.writer.append(ti, to, f, std, repeats, time.time())
        if self.checks is not None:
            self.checks.add(line)
        if self.watch is not None:
            self.watch.sample(ti, to, f, std, repeats)

    def close(self) -> None:
        if self.checks is not None:
            self.checks.close()
        if self.writer is not None:
            try:
                self.writer.close()
            except OSError as e:  # every row was fsynced when appended; only the final sync failed
                log.info("closing %s: %s", self.eng.slice_path, e)
