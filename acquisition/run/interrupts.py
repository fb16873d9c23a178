"""Ctrl-C and SIGTERM during a capture: :class:`SignalGuard` turns them into flags that the capture checks at safe
places, so that no signal ends in a traceback, however it is timed.

A Python signal handler runs between two bytecodes of the main thread, wherever that is: in the middle of a log
record being written, of a module being imported (``tqdm`` on the first log line), of a ``BufferedWriter`` call.
Anything it does that takes a lock, imports or writes can meet the half-done operation it interrupted (a second
SIGTERM 20 ms after the first met the first one's log record importing ``tqdm``: "--- Logging error ---" and a
traceback). So the handler only sets flags and puts its message on a :class:`queue.SimpleQueue` (whose ``put`` is
reentrant, made for such callers); a reporter thread logs the messages at once, from outside the handler, and
:meth:`SignalGuard.drain` logs what is left from the main thread when the capture ends.
"""

from __future__ import annotations

import logging
import queue
import signal
import threading
from typing import Any, ClassVar

from acquisition.errors import CaptureInterrupted

log = logging.getLogger("acquisition.engine")

__all__ = ["SignalGuard"]


class SignalGuard:
    """SIGINT/SIGTERM become flags, main thread only: the first asks the capture to stop after the current step
    (:meth:`check` raises :class:`CaptureInterrupted` there); a second also aborts the parking
    (:meth:`check_abort`). The handler itself never raises, logs, imports or writes (see the module docstring);
    the exit status is the first signal's. Use as a context manager around the capture. Leaving it gives the
    previous handlers back, except after a signal in a program that set :attr:`ignore_after_signal` (it ends with
    the first signal's status: further SIGINT/SIGTERM are ignored)."""

    #: set by a program that exits once a signal stopped its capture (gonio-capture): see :meth:`__exit__`
    ignore_after_signal: ClassVar[bool] = False

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and threading.current_thread() is threading.main_thread()
        self.signum: int | None = None
        self.abort = False
        self._old: dict[int, Any] = {}
        self._messages: queue.SimpleQueue[str | None] = queue.SimpleQueue()
        self._reporter: threading.Thread | None = None

    def __enter__(self) -> SignalGuard:
        if self.enabled:
            self._reporter = threading.Thread(target=self._report, name="gonio-capture signals", daemon=True)
            self._reporter.start()
            for s in (signal.SIGINT, signal.SIGTERM):
                self._old[s] = signal.getsignal(s)
                signal.signal(s, self._handler)
        return self

    def _handler(self, signum: int, frame: Any) -> None:
        # flags and a reentrant queue only: this may run in the middle of anything (see the module docstring)
        name = _NAMES.get(signum, str(signum))
        if self.signum is None:
            self.signum = signum
            self._messages.put(f"{name} received: stopping after the current step (send it again to abort parking)")
        elif not self.abort:
            self.abort = True
            again = "again" if signum == self.signum else f"after {_NAMES.get(self.signum, str(self.signum))}"
            self._messages.put(f"{name} received {again}: not waiting for the arms to park")

    def _report(self) -> None:
        """The reporter thread: logs the handler's messages as they come, until :meth:`drain` sends None."""
        while True:
            msg = self._messages.get()
            if msg is None:
                return
            log.warning("%s", msg)

    def drain(self) -> None:
        """Log every message the handler left (main thread, outside the handler) and stop the reporter thread; a
        signal after this is logged by the next :meth:`drain` (called again on exit)."""
        if self._reporter is not None:
            self._messages.put(None)
            self._reporter.join(timeout=5.0)
            self._reporter = None
        while True:
            try:
                msg = self._messages.get_nowait()
            except queue.Empty:
                return
            if msg is not None:
                log.warning("%s", msg)

    def check(self) -> None:
        if self.signum is not None:
            raise CaptureInterrupted(f"interrupted by {_NAMES.get(self.signum, self.signum)}", self.signum)

    def check_abort(self) -> None:
        """The cancel check while parking: only a second signal stops it."""
        if self.abort:
            assert self.signum is not None
            raise CaptureInterrupted(f"parking aborted by a second {_NAMES.get(self.signum, self.signum)}",
                                     self.signum)

    def __exit__(self, *exc: object) -> None:
        for s, h in self._old.items():
            # a program that ends once a signal stopped the capture (gonio-capture: ignore_after_signal) ignores a
            # second signal arriving after this point (20 ms later, while it prints where to resume) rather than
            # handing it to the default action, which would kill it (-15) or raise KeyboardInterrupt mid-message;
            # otherwise (a lab script that goes on) the previous handlers come back as they were
            ignore = self.signum is not None and SignalGuard.ignore_after_signal
            signal.signal(s, signal.SIG_IGN if ignore else h)
        self.drain()


#: Signal names, looked up without calling into the ``enum`` machinery from the handler.
_NAMES = {signal.SIGINT: "SIGINT", signal.SIGTERM: "SIGTERM"}
