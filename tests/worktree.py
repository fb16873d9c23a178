"""What the test suite leaves in the working tree: tests write only to temporary folders.

:func:`snapshot` lists the repository's untracked, ignored and modified files (``git status --porcelain
--ignored --untracked-files=all``) with their modification times, leaving out what a run may write: the
environment (``.venv``), bytecode and tool caches. :func:`left_behind` compares two snapshots: the files that
appeared or changed between them. conftest.py takes one when the session starts and fails the session, naming the
files, if its end differs.
"""

from __future__ import annotations

import subprocess
from pathlib import Path

#: path components a run may create or change: the environment, bytecode, tool caches, build metadata
ALLOWED_PARTS = (".venv", "__pycache__", ".pytest_cache", ".hypothesis", ".ruff_cache", ".mypy_cache",
                 ".import_linter_cache")
ALLOWED_SUFFIXES = (".egg-info", ".pyc")

Snapshot = dict[str, int]


def _allowed(path: str) -> bool:
    parts = Path(path.rstrip("/")).parts
    return any(p in ALLOWED_PARTS or p.endswith(ALLOWED_SUFFIXES) for p in parts)


def snapshot(root: Path) -> Snapshot | None:
    """Untracked, ignored and modified paths under ``root`` -> their mtime (ns; -1 if gone); None when ``root`` is
    not a git checkout (an unpacked sdist) or git is missing."""
    try:
        r = subprocess.run(["git", "status", "--porcelain", "--ignored", "--untracked-files=all", "-z"], cwd=root,
                           capture_output=True, text=True, timeout=60)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if r.returncode != 0:
        return None
    out: Snapshot = {}
    entries = r.stdout.split("\0")
    k = 0
    while k < len(entries):
        entry = entries[k]
        k += 1
        if len(entry) < 4:
            continue
        status, path = entry[:2], entry[3:]
        if status[0] in "RC":  # a rename's source follows
            k += 1
        if _allowed(path):
            continue
        try:
            out[path] = (root / path).lstat().st_mtime_ns
        except OSError:
            out[path] = -1
    return out


def left_behind(before: Snapshot, after: Snapshot) -> list[str]:
    """The paths of ``after`` that are new or changed since ``before``."""
    return sorted(p for p, t in after.items() if before.get(p) != t)
