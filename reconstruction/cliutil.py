"""Small pieces the command-line programs share: one-line usage errors and warnings as plain lines."""

from __future__ import annotations

import argparse
import sys
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from typing import Any, NoReturn

__all__ = ["OneLineParser", "plain_warnings"]


class OneLineParser(argparse.ArgumentParser):
    """An ArgumentParser whose usage errors are one line naming the problem and pointing at ``--help`` (exit 2),
    instead of the whole usage block."""

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
