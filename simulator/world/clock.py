"""Simulated time.

``time_scale > 0``: simulated time runs at ``time_scale`` x wall-clock time (1 = real time) and waiting really
sleeps ``dt / time_scale`` wall seconds. ``time_scale == 0``: "as fast as possible" - simulated time stands
still and only moves when the bench advances it (a detector integration, a dwell, or a status query that
completes a pending motion); nothing ever sleeps.

Packet round trips are never scaled: the Dynamixel SDK's reply deadline is wall-clock.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable


class SimClock:
    """Monotonic simulated clock in seconds, starting at 0."""

    def __init__(self, time_scale: float = 0.0) -> None:
        if time_scale < 0:
            raise ValueError("time_scale must be >= 0")
        self.time_scale = float(time_scale)
        self._offset = 0.0
        self._wall0 = time.monotonic()
        self._lock = threading.Lock()
        #: called with the new time after every jump of fast time (an emulated detector board follows it)
        self.on_jump: list[Callable[[float], None]] = []

    def _jumped(self) -> None:
        for f in self.on_jump:
            f(self._offset)

    @property
    def fast(self) -> bool:
        """True when time_scale == 0 (time jumps instead of flowing)."""
        return self.time_scale == 0.0

    def now(self) -> float:
        """Current simulated time (s)."""
        if self.fast:
            return self._offset
        return self._offset + self.time_scale * (time.monotonic() - self._wall0)

    def advance(self, dt: float) -> None:
        """Let ``dt`` simulated seconds pass (jump in fast mode, sleep ``dt / time_scale`` otherwise)."""
        if dt <= 0:
            return
        if self.fast:
            with self._lock:
                self._offset += dt
            self._jumped()
        else:
            time.sleep(dt / self.time_scale)

    def jump_to(self, t: float) -> None:
        """Fast mode only: move simulated time forward to ``t`` without waiting (no-op in scaled mode)."""
        if self.fast:
            with self._lock:
                if t <= self._offset:
                    return
                self._offset = t
            self._jumped()


class Paced:
    """What a line-speaking virtual device does with the simulated time its replies take (``_advance``): at once
    in fast time; in scaled time it adds up, and the bench sleeps it outside its lock (:meth:`take_wait`), so the
    other ports stay responsive. A device sets ``clock`` (and ``_wait = 0.0``) in its ``__init__``."""

    clock: SimClock
    _wait: float = 0.0

    def _advance(self, dt: float) -> None:
        """Let ``dt`` simulated seconds pass for a reply being made."""
        if self.clock.fast:
            self.clock.advance(dt)
        else:
            self._wait += dt

    def take_wait(self) -> float:
        """Simulated seconds the replies just produced must be delayed by (scaled time only); resets it."""
        w, self._wait = self._wait, 0.0
        return w
