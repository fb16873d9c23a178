"""``DIR/progress.json``: how far a capture is, for its live view (:mod:`acquisition.live`), written only when
the capture is watched (``gonio-capture --live``).

It holds the points planned and done, the wall time since the first sample, the time left (the remaining points at
the rate of those measured so far; before two samples, the time model's estimate), the last sample (its angles,
f_r and standard deviation averaged over the channels) and the run's status. It is written atomically (a
temporary file renamed over it, not fsynced: it is a view, not a record), at most every :data:`MIN_INTERVAL_S`
wall seconds while samples land and always at the end, and a failure to write it is logged once and never reaches
the capture: the slice and the run record are what is kept.
"""

from __future__ import annotations

import json
import logging
import os
import time
from pathlib import Path
from typing import Any

log = logging.getLogger("acquisition.progress")

__all__ = ["ProgressFile", "PROGRESS_NAME", "MIN_INTERVAL_S"]

PROGRESS_NAME = "progress.json"
#: Shortest wall time between two writes while samples land (s).
MIN_INTERVAL_S = 0.25


class ProgressFile:
    """The progress of one run of a capture into ``path``; ``estimate_s``: the time model's estimate of the run
    (bench seconds). Every method returns quietly, whatever happens to the file."""

    def __init__(self, path: str | Path, estimate_s: float = 0.0, points_planned: int = 0) -> None:
        self.path = Path(path)
        self.state: dict[str, Any] = {"status": "running", "points_total": points_planned, "points_done": 0,
                                      "samples_this_run": 0, "estimate_s": estimate_s, "elapsed_s": 0.0,
                                      "time_left_s": estimate_s, "last": None, "message": "", "pid": os.getpid()}
        self._t0 = time.monotonic()
        self._t_first: float | None = None
        self._done_first = 0
        self._last_write = -1e9
        self._failed = False
        self._write(force=True)

    def announce(self, total: int, done: int) -> None:
        """The plan's points (``total``) and those already in the slice (``done``)."""
        self.state["points_total"] = int(total)
        self.state["points_done"] = int(done)
        self._write(force=True)

    def sample(self, theta_i_deg: float, theta_o_deg: float, f: list[float], std: list[float], repeats: int) -> None:
        """A sample saved: its angles (degrees), f_r and standard deviation (1/sr) per channel, repeats."""
        now = time.monotonic()
        st = self.state
        if self._t_first is None:
            self._t_first, self._done_first = now, st["points_done"]
        st["points_done"] += 1
        st["samples_this_run"] += 1
        n = len(f) or 1
        st["last"] = {"theta_i_deg": theta_i_deg, "theta_o_deg": theta_o_deg, "f_r": sum(f) / n,
                      "std": sum(std) / n, "repeats": repeats, "channels": len(f)}
        st["elapsed_s"] = now - self._t0
        left = max(st["points_total"] - st["points_done"], 0)
        measured = st["points_done"] - self._done_first
        if measured >= 2:  # the rate of this run's samples after the first
            st["time_left_s"] = left * (now - self._t_first) / (measured - 1)
        self._write()

    def finish(self, status: str, message: str = "") -> None:
        """The run ended with ``status`` (``complete``, ``interrupted``, ``failed``)."""
        self.state.update(status=status, message=message.splitlines()[0] if message else "",
                          elapsed_s=time.monotonic() - self._t0)
        if status == "complete":
            self.state["time_left_s"] = 0.0
        self._write(force=True)

    def _write(self, force: bool = False) -> None:
        now = time.monotonic()
        if self._failed or (not force and now - self._last_write < MIN_INTERVAL_S):
            return
        self._last_write = now
        self.state["updated_unix_s"] = time.time()
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.tmp")
        try:
            tmp.write_text(json.dumps(self.state), encoding="utf-8")
            os.replace(tmp, self.path)
        except OSError as e:  # a full disk: the live view goes stale, the capture goes on
            self._failed = True
            log.info("the live view's %s cannot be written (%s); it stops updating", self.path, e)
            try:
                tmp.unlink()
            except OSError:
                pass
