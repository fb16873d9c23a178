"""The arms' angles from GRBL's own host simulator (grbl-sim), for a bench whose arms run on the real firmware's
code while the detector is simulated here (``gonio-sim serve --arm-steps FILE --arm-blocks FILE``).

grbl-sim writes two files (its README): ``-s FILE -r T`` the step counters every T s of its simulated time,
``time x_steps, y_steps, z_steps, spindle`` under a ``# block number N`` header per block, and ``-b FILE`` one line
per planned block, ``x, y, z, entry_speed_sqr`` (its cumulative target in steps). The step file prints a block's
header when the stepper takes the block from the planner, with the counters of that moment, and then samples
while the block runs; but the block leaves the planner when its last segments are *prepared*, up to a few 10-ms
segments before its last step, and nothing is printed while GRBL is idle. So after a move the step file's last
line can be short of where the arms stopped. The track therefore takes each block's *start* from the step file
(the counters printed with its header: the arms at rest, since the capture waits for ``Idle`` between moves) and
its *length* from the block file (the difference of consecutive targets), and the arms at rest are at start +
length. Before the block file has the newest block, the step file's last line is used.

After a block cut short (a feed hold then a reset, or a reset in motion) the track still says its end until the
next block's header gives the true counters: the capture reads nothing in between (it stops, or moves first).

``steps = zero_offset + direction * units_per_deg * deg`` (the bench file's ``[axes.*]``): GRBL's step count is the
bench's controller unit.
"""

from __future__ import annotations

import threading
from pathlib import Path
from typing import Protocol

__all__ = ["GrblSimTrack"]


class _Axis(Protocol):
    def units_to_deg(self, units: float) -> float: ...


class GrblSimTrack:
    """``track(t)`` -> (theta_i, theta_o) in degrees: the arms after the newest block grbl-sim has started (``t``,
    the detector's clock, is not grbl-sim's and is ignored: the files are read as they are now)."""

    def __init__(self, steps: str | Path, blocks: str | Path, light: _Axis, detector: _Axis) -> None:
        self.steps_path, self.blocks_path = Path(steps), Path(blocks)
        self.light, self.detector = light, detector
        self._lock = threading.Lock()
        self._steps_off = self._blocks_off = 0
        self._steps_rest = self._blocks_rest = ""
        self.last = (0, 0)  # the newest step-file counters (x, y)
        self.starts: list[tuple[int, int]] = []  # per block: the counters printed with its header
        self.targets: list[tuple[int, int]] = []  # per block: grbl-sim's cumulative target

    def _read(self, path: Path, off: int, rest: str) -> tuple[list[str], int, str]:
        try:
            with open(path, encoding="ascii", errors="replace") as fh:
                fh.seek(off)
                text = fh.read()
                off = fh.tell()
        except FileNotFoundError:
            return [], off, rest
        text = rest + text
        lines = text.split("\n")
        return lines[:-1], off, lines[-1]  # an unfinished last line waits for its newline

    def refresh(self) -> None:
        """Read what grbl-sim wrote since the last call."""
        lines, self._steps_off, self._steps_rest = self._read(self.steps_path, self._steps_off, self._steps_rest)
        for ln in lines:
            ln = ln.strip()
            if ln.startswith("# block number"):
                self.starts.append(self.last)
            elif ln:
                parts = ln.replace(",", " ").split()
                if len(parts) >= 3:
                    self.last = (int(parts[1]), int(parts[2]))
        lines, self._blocks_off, self._blocks_rest = self._read(self.blocks_path, self._blocks_off,
                                                                self._blocks_rest)
        for ln in lines:
            parts = [p.strip() for p in ln.split(",")]
            if len(parts) >= 3 and parts[0]:
                self.targets.append((int(parts[0]), int(parts[1])))

    def steps(self) -> tuple[int, int]:
        """The arms' step counters (x, y) now: the newest block's start plus its length, else the last line."""
        with self._lock:
            self.refresh()
            n = len(self.starts)
            if n == 0 or len(self.targets) < n:
                return self.last
            prev = self.targets[n - 2] if n >= 2 else (0, 0)
            start, end = self.starts[n - 1], self.targets[n - 1]
            return (start[0] + end[0] - prev[0], start[1] + end[1] - prev[1])

    def __call__(self, t: float) -> tuple[float, float]:
        x, y = self.steps()
        return self.light.units_to_deg(x), self.detector.units_to_deg(y)
