"""The live view as a child process of the capture: started before it, stopped after it (``gonio-capture
--live``). Nothing here can stop or slow the capture: the server is another process at a lower priority that only
reads the capture's files; starting it may fail (a port in use), which is one warning, and the capture goes on."""

from __future__ import annotations

import json
import logging
import os
import select
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import IO

log = logging.getLogger("acquisition.live")

__all__ = ["LiveView"]


class LiveView:
    """The live view of the capture in ``folder`` on ``host``:``port`` (0: a free port); ``allow_hosts``: host names
    it may be reached by beside localhost and ``host`` (IP addresses always may)."""

    def __init__(self, folder: str | Path, host: str = "127.0.0.1", port: int = 0,
                 allow_hosts: tuple[str, ...] = ()) -> None:
        self.folder = Path(folder)
        self.host = host
        self.port = port
        self.allow_hosts = tuple(allow_hosts)
        self.proc: subprocess.Popen[bytes] | None = None
        self.url: str | None = None
        self._err: IO[bytes] | None = None

    def start(self, timeout_s: float = 15.0) -> str | None:
        """Start the server and return its URL; None (and a warning) if it cannot be started."""
        argv = [sys.executable, "-m", "acquisition.live", "--dir", str(self.folder), "--host", self.host,
                "--port", str(self.port), "--parent", str(os.getpid()),
                *(a for n in self.allow_hosts for a in ("--allow-host", n))]
        self._err = tempfile.TemporaryFile()  # its stderr (a full pipe could block it): read back on failure
        try:
            self.proc = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                         stderr=self._err, start_new_session=True)
        except OSError as e:
            log.warning("live view: cannot start %s: %s; the capture goes on without it", argv[0], e)
            return None
        assert self.proc.stdout is not None
        line = b""
        deadline = time.monotonic() + timeout_s
        fd = self.proc.stdout.fileno()
        while not line.endswith(b"\n"):
            r, _, _ = select.select([fd], [], [], max(deadline - time.monotonic(), 0.0))
            ch = os.read(fd, 1) if r else b""
            if not ch:
                if r:  # end of its output: it is exiting, and its stderr is complete once it has
                    try:
                        self.proc.wait(timeout_s)
                    except subprocess.TimeoutExpired:
                        pass
                self._err.seek(0)
                err = self._err.read().decode(errors="replace").strip()
                self.stop()
                log.warning("live view did not start (%s); the capture goes on without it",
                            err.splitlines()[-1] if err else "no answer")
                return None
            line += ch
        try:
            self.url = str(json.loads(line)["url"])
        except (ValueError, KeyError, TypeError):
            self.stop()
            log.warning("live view: unexpected first line %r; the capture goes on without it", line[:200])
            return None
        return self.url

    def stop(self, timeout_s: float = 3.0) -> None:
        """Stop the server (SIGTERM, then SIGKILL after ``timeout_s``). Never raises."""
        p = self.proc
        if p is None:
            return
        try:
            if p.poll() is None:
                p.terminate()
                try:
                    p.wait(timeout_s)
                except subprocess.TimeoutExpired:
                    p.kill()
                    p.wait()
            for fh in (p.stdout, self._err):
                if fh is not None:
                    fh.close()
        except OSError:  # pragma: no cover - already gone
            pass
