"""A small on-disk cache of computed arrays (``$XDG_CACHE_HOME/gonio-brdf``, else ``~/.cache/gonio-brdf``).

Tables that cost a noticeable fraction of a second to build (the lobes' albedo tables, a prior's basis) are built
once per machine instead of once per process. A file is written atomically; one that cannot be read is rebuilt;
a cache that cannot be written only costs the build again.
"""

from __future__ import annotations

import hashlib
import os
import zipfile
from collections.abc import Callable, Sequence
from contextvars import ContextVar
from pathlib import Path
from typing import TypeVar

import numpy as np
from numpy.typing import NDArray

from reconstruction.atomic import atomic_open

__all__ = ["cache_dir", "cached_arrays", "cached_decoded", "BUILD_PROGRESS", "BUILT", "report_build"]

T = TypeVar("T")

#: who hears how a long build goes (a command line's progress bar): called with (what, done, total); None: nobody
BUILD_PROGRESS: ContextVar[Callable[[str, int, int], None] | None] = ContextVar("build_progress", default=None)
#: who hears where a build's cache file went: called with (what, path, size in bytes, seconds it took to build)
BUILT: ContextVar[Callable[[str, Path, int, float], None] | None] = ContextVar("built", default=None)


def report_build(what: str, done: int, total: int) -> None:
    """Tell :data:`BUILD_PROGRESS` (if anyone listens) that ``done`` of ``total`` parts of ``what`` are built."""
    hook = BUILD_PROGRESS.get()
    if hook is not None:
        hook(what, done, total)


def cache_dir() -> Path:
    """The project's cache folder (not created here)."""
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "gonio-brdf"


def cached_arrays(name: str, key: str, build: Callable[[], Sequence[NDArray[np.float64]]],
                  what: str | None = None) -> tuple[NDArray[np.float64], ...]:
    """The arrays ``build()`` returns, read from ``cache_dir()/NAME-HASH.npz`` when a file for this ``key`` (every
    input the arrays depend on, as text) is there, else built and saved. ``what``: the build described for a
    person; then :data:`BUILT` hears where the file went."""
    return cached_decoded(name, key, build, lambda arrays: arrays, what)


def cached_decoded(name: str, key: str, build: Callable[[], Sequence[NDArray]],
                   decode: Callable[[tuple[NDArray, ...]], T], what: str | None = None) -> T:
    """``decode`` of the arrays ``build()`` returns (a compact form: what is saved), read as
    :func:`cached_arrays` reads them. A file whose arrays ``decode`` refuses (ValueError: damaged, or of another
    coding) is built again; the arrays just built are decoded too, so the first run sees what later runs read."""
    import time

    path = cache_dir() / f"{name}-{hashlib.sha1(key.encode()).hexdigest()[:16]}.npz"
    try:
        with np.load(path) as z:
            return decode(tuple(z[f"a{k}"] for k in range(len(z.files))))
    except (OSError, ValueError, KeyError, EOFError, zipfile.BadZipFile):
        pass  # absent or damaged: built again
    t0 = time.perf_counter()
    out = tuple(np.asarray(a) for a in build())
    seconds = time.perf_counter() - t0
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        with atomic_open(path, "wb") as fh:
            np.savez(fh, **{f"a{k}": a for k, a in enumerate(out)})
    except OSError:
        return decode(out)  # no cache: the next process builds again
    hook = BUILT.get()
    if what is not None and hook is not None:
        hook(what, path, path.stat().st_size, seconds)
    return decode(out)
