"""Atomic file writes: never leave a half-written file under the target name."""

from __future__ import annotations

import errno
import os
import tempfile
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import IO, Any

__all__ = ["atomic_open", "atomic_path", "NO_SPACE_ERRNOS", "is_no_space"]

#: errno values that mean "the disk (or quota, or the process's file size limit) is full".
NO_SPACE_ERRNOS = frozenset({errno.ENOSPC, errno.EDQUOT, errno.EFBIG})


def is_no_space(e: BaseException) -> bool:
    """True for an OSError that says the disk, a quota or the file size limit is full."""
    return isinstance(e, OSError) and e.errno in NO_SPACE_ERRNOS


def _named(e: OSError, path: Path, tmp: str) -> OSError:
    """``e`` naming ``path`` (the target) instead of the temporary file or nothing."""
    if e.errno is None or (e.filename not in (None, tmp)):
        return e
    return OSError(e.errno, e.strerror or os.strerror(e.errno), str(path))


def _umask() -> int:
    umask = os.umask(0)
    os.umask(umask)
    return umask


@contextmanager
def atomic_open(path: str | Path, mode: str = "wb", **kwargs: Any) -> Iterator[IO[Any]]:
    """Open a temporary file beside ``path`` for writing; on success fsync it and rename it over ``path``.

    On any exception the temporary file is removed and ``path`` is untouched; an OSError names ``path`` (not the
    temporary file). The file gets the ordinary permissions (0666 minus the umask), not mkstemp's 0600. ``mode``
    is "wb" or "w"; ``kwargs`` go to open().
    """
    path = Path(path)
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open: mode must be 'w' or 'wb', got {mode!r}")
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", suffix=".tmp", dir=path.parent)
    except OSError as e:
        raise _named(e, path, "") from None
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(e, OSError):
            raise _named(e, path, tmp) from None
        raise


@contextmanager
def atomic_path(path: str | Path) -> Iterator[str]:
    """A temporary file name beside ``path`` (same suffix) for writers that need a name, not a file object (e.g.
    OpenEXR); on success the file is fsynced and renamed over ``path``, on any exception it is removed."""
    path = Path(path)
    try:
        fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f".tmp{path.suffix}", dir=path.parent)
    except OSError as e:
        raise _named(e, path, "") from None
    try:
        os.fchmod(fd, 0o666 & ~_umask())
        os.close(fd)
        yield tmp
        fd = os.open(tmp, os.O_RDONLY)
        try:
            os.fsync(fd)
        finally:
            os.close(fd)
        os.replace(tmp, path)
    except BaseException as e:
        try:
            os.unlink(tmp)
        except FileNotFoundError:
            pass
        if isinstance(e, OSError):
            raise _named(e, path, tmp) from None
        raise
