"""Small pieces the command-line programs share: one-line usage errors and warnings as plain lines."""

from __future__ import annotations

import argparse
import re
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, NoReturn

__all__ = ["OneLineParser", "plain_warnings", "plain_text"]

_ROLE = re.compile(r":(?:py:)?(?:func|class|mod|meth|data|attr|obj|exc):`~?([^`<]*?)(?:\s*<[^>]*>)?`")


def plain_text(text: str) -> str:
    """reST as a terminal shows it: ``code`` and :func:`roles` as their plain text (a ``~`` role as its last
    name), so a docstring can be a command's ``--help``."""
    text = _ROLE.sub(lambda m: m.group(1), text)
    return re.sub(r"``([^`]+)``", r"\1", text)


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line naming the problem and pointing at ``--help`` (exit 2),
    instead of the whole usage block; its description may be reST (a module docstring): it is shown plain."""

    def __init__(self, *args: Any, description: str | None = None, **kwargs: Any) -> None:
        super().__init__(*args, description=plain_text(description) if description else description, **kwargs)

    def error(self, message: str) -> NoReturn:
        self.exit(2, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


@contextmanager
def plain_warnings(prog: str) -> Iterator[None]:
    """Inside, a Python warning reaches the user as one line ``PROG: warning: MESSAGE`` (no source path)."""

    def show(message: Any, category: Any, filename: str, lineno: int, file: Any = None, line: Any = None) -> None:
        print(f"{prog}: warning: {message}", file=sys.stderr)

    with warnings.catch_warnings():
        warnings.simplefilter("default")
        warnings.simplefilter("ignore", RuntimeWarning)
        warnings.showwarning = show
        yield


#: glibc's mallopt parameters (malloc.h): M_TRIM_THRESHOLD, M_TOP_PAD, M_MMAP_THRESHOLD
_M_TRIM_THRESHOLD, _M_TOP_PAD, _M_MMAP_THRESHOLD = -1, -2, -3


def keep_freed_memory() -> bool:
    """Ask glibc's allocator to keep the memory numpy frees for the next arrays instead of returning it to the
    kernel: arrays up to 32 MB from the heap (glibc's largest mmap threshold), the heap not trimmed below 1 GB,
    grown 64 MB at a time. By default every array above 128 KB (rising with use, to 32 MB) is a fresh mapping
    whose pages the kernel zeroes when first touched; on the 2-core virtual machine a first touch costs about
    as much as computing on the page, so a reconstruction spent a third of its time in the kernel
    (benchmarks/bench_speed.py: auto's median wall time 2.12 -> 1.85 s, its system time 0.93 -> 0.46 s, page
    faults 66 k -> 52 k on the demo). Whole-process tuning for the command-line tools only; returns whether it
    applied (glibc on Linux; elsewhere nothing changes)."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes

        libc = ctypes.CDLL("libc.so.6")
        return all(libc.mallopt(p, v) == 1 for p, v in ((_M_MMAP_THRESHOLD, 32 << 20), (_M_TRIM_THRESHOLD, 1 << 30),
                                                         (_M_TOP_PAD, 64 << 20)))
    except (OSError, AttributeError):  # not glibc (musl, another libc): its own defaults
        return False
