"""One capture per output folder: an OS lock (``fcntl.flock``) on ``DIR/capture.lock``.

The lock is held for the whole run, so a second capture (or a ``--resume``) of the same folder refuses at once
with :class:`OutDirLocked`, naming the folder and the PID that holds it. The kernel releases an flock when its
holder dies, however it dies (a SIGKILL included): a lock file left behind by a killed capture still names the
dead PID but is not locked, and the next capture takes it over (and says so) - a killed capture stays resumable.
The PID in the file is for the message only; the lock itself is the flock, never the PID. A run that ends
removes the file (while it still holds the lock), so a lock file in a folder means a capture runs there or died;
a capture that took the lock on a file removed meanwhile (it opened the old one) tries again on the new one.
"""

from __future__ import annotations

import errno
import fcntl
import os
import time
from pathlib import Path
from typing import NoReturn

from acquisition.errors import PlanError

__all__ = ["LOCK_NAME", "OutDirLocked", "OutLock"]

LOCK_NAME = "capture.lock"


class OutDirLocked(PlanError):
    """Another process holds the output folder's lock; ``pid`` is the holder's PID (None if unknown)."""

    def __init__(self, message: str, pid: int | None) -> None:
        super().__init__(message)
        self.pid = pid


def _read_pid(fd: int) -> int | None:
    try:
        os.lseek(fd, 0, os.SEEK_SET)
        text = os.read(fd, 64).decode("ascii", "replace").strip()
        return int(text) if text.isdigit() else None
    except OSError:  # pragma: no cover - unreadable lock file
        return None


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # pragma: no cover - another user's process
        return True
    return True


class OutLock:
    """The lock of output folder ``out`` (which must exist). :meth:`acquire` / :meth:`release`."""

    def __init__(self, out: str | Path) -> None:
        self.out = Path(out)
        self.path = self.out / LOCK_NAME
        self.fd: int | None = None

    def acquire(self) -> int | None:
        """Take the lock without waiting. Returns the PID of an earlier holder that died without releasing it
        (a stale lock, taken over), else None. Raises :class:`OutDirLocked` if a live process holds it and
        :class:`PlanError` if the lock file cannot be created (a read-only folder)."""
        for _ in range(100):  # a holder that removes the file as this one locks it: again, on the new file
            fd = self._open()
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except OSError as e:
                self._refuse(fd, e)
            if self._is_current(fd):
                break
            os.close(fd)
        else:  # pragma: no cover - a folder whose lock file is removed again and again
            raise PlanError(f"--out {self.out}: cannot lock {self.path}: it is removed as soon as it is made")
        return self._take(fd)

    def _open(self) -> int:
        try:
            return os.open(self.path, os.O_RDWR | os.O_CREAT | os.O_CLOEXEC, 0o666)
        except OSError as e:
            raise PlanError(f"--out {self.out}: cannot create the lock file {LOCK_NAME} ({e.strerror or e}); "
                            "the output folder must be writable") from None

    def _is_current(self, fd: int) -> bool:
        """Whether the locked ``fd`` is still the file at :attr:`path` (its holder may have removed it)."""
        try:
            return os.fstat(fd).st_ino == os.stat(self.path).st_ino
        except FileNotFoundError:
            return False

    def _refuse(self, fd: int, e: OSError) -> NoReturn:
        """Another process holds the lock (or it cannot be taken): close ``fd`` and raise, naming the holder."""
        pid = _read_pid(fd)
        for _ in range(50):  # the holder writes its PID right after taking the lock: give it a moment
            if pid is not None:
                break
            time.sleep(0.01)
            pid = _read_pid(fd)
        os.close(fd)
        if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
            raise PlanError(f"--out {self.out}: cannot lock {self.path} ({e.strerror or e})") from None
        who = f"PID {pid}" if pid is not None else "another process"
        raise OutDirLocked(f"--out {self.out}: in use by another capture ({who}, holding {self.path}); wait "
                           "for it to finish or choose another --out; nothing was moved", pid) from None

    def _take(self, fd: int) -> int | None:
        previous = _read_pid(fd)
        try:
            os.ftruncate(fd, 0)
            os.lseek(fd, 0, os.SEEK_SET)
            os.write(fd, f"{os.getpid()}\n".encode())
            os.fsync(fd)
        except OSError:  # a full disk: the flock protects the folder all the same
            pass
        self.fd = fd
        if previous is not None and previous != os.getpid() and not _alive(previous):
            return previous
        return None

    def release(self) -> None:
        """Give the lock up and remove its file (emptied if it cannot be removed: no holder)."""
        if self.fd is None:
            return
        try:
            os.unlink(self.path)
        except OSError:  # a folder that turned read-only: the file stays, emptied
            try:
                os.ftruncate(self.fd, 0)
            except OSError:  # pragma: no cover - read-only by now
                pass
        try:
            fcntl.flock(self.fd, fcntl.LOCK_UN)
        finally:
            os.close(self.fd)
            self.fd = None
