"""What the test suite leaves in the working tree: tests write only to temporary folders.

Two witnesses, so that the guard looks at what the tests write and not at the git-ignored folders a user works in
(a capture into ``out/`` while the tests run is the user's, not the tests'):

* :func:`snapshot` lists the repository's untracked (not ignored) and modified files (``git status --porcelain
  --untracked-files=all``) with their modification times, leaving out what a run may write: the environment
  (``.venv``), bytecode and tool caches; :func:`left_behind` compares two snapshots. Ignored paths are left out
  unless ``ignored=True``.
* :func:`start_audit` installs an audit hook (``sys.addaudithook``, event ``open``) in a test process (the
  controller and every pytest-xdist worker) that records each file under the repository that the process opens
  for writing, ignored or not; :func:`audited` collects them from every process of the session.

conftest.py takes a snapshot when the session starts, audits every test process, and fails the session, naming
the files, if the end's snapshot differs or an audited file is left in the tree. Files written by other programs
the tests start as child processes are seen by the snapshot only (outside ignored folders).
"""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path
from typing import Any

#: path components a run may create or change: the environment, bytecode, tool caches, build metadata
ALLOWED_PARTS = (".venv", "__pycache__", ".pytest_cache", ".hypothesis", ".ruff_cache", ".mypy_cache",
                 ".import_linter_cache")
ALLOWED_SUFFIXES = (".egg-info", ".pyc")

Snapshot = dict[str, int]


def _allowed(path: str) -> bool:
    parts = Path(path.rstrip("/")).parts
    return any(p in ALLOWED_PARTS or p.endswith(ALLOWED_SUFFIXES) for p in parts)


def snapshot(root: Path, ignored: bool = False) -> Snapshot | None:
    """Untracked and modified paths under ``root`` (and the git-ignored ones with ``ignored``) -> their mtime (ns;
    -1 if gone); None when ``root`` is not a git checkout (an unpacked sdist) or git is missing."""
    try:
        r = subprocess.run(["git", "status", "--porcelain", *(["--ignored"] if ignored else []),
                            "--untracked-files=all", "-z"], cwd=root, capture_output=True, text=True, timeout=60)
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


#: the environment variable naming the folder where every audited test process writes what it wrote
AUDIT_ENV = "GONIO_TEST_WRITES"
_WRITE_FLAGS = os.O_WRONLY | os.O_RDWR | os.O_CREAT | os.O_APPEND | os.O_TRUNC


def start_audit(root: Path, log_dir: Path) -> None:
    """Record, from now on, every path under ``root`` this process opens for writing (but what a run may write:
    bytecode, caches, the environment) in ``log_dir/<pid>.txt``, one repository-relative path a line. An audit hook
    cannot be removed: call it once per process."""
    prefix = os.path.join(os.path.abspath(root), "")
    out = Path(log_dir) / f"{os.getpid()}.txt"
    seen: set[str] = set()
    busy = [False]

    def hook(event: str, args: tuple[Any, ...]) -> None:
        if event != "open" or busy[0]:
            return
        path, mode, flags = (tuple(args) + (None, None, None))[:3]
        if not isinstance(path, (str, bytes, os.PathLike)):
            return  # a file descriptor
        writes = (any(c in mode for c in "wax+") if isinstance(mode, str)
                  else isinstance(flags, int) and bool(flags & _WRITE_FLAGS))
        if not writes:
            return
        full = os.path.abspath(os.fsdecode(path))
        if not full.startswith(prefix):
            return
        rel = full[len(prefix):]
        if rel in seen or _allowed(rel):
            return
        seen.add(rel)
        busy[0] = True
        try:
            with open(out, "a", encoding="utf-8") as fh:
                fh.write(rel + "\n")
        except OSError:  # the session's folder is gone: nothing to report to
            pass
        finally:
            busy[0] = False

    sys.addaudithook(hook)


def audited(root: Path, log_dir: Path) -> list[str]:
    """The repository-relative paths the audited processes wrote (:func:`start_audit`) that are still there."""
    paths: set[str] = set()
    for f in Path(log_dir).glob("*.txt"):
        try:
            paths.update(ln for ln in f.read_text(encoding="utf-8").splitlines() if ln)
        except OSError:
            continue
    return sorted(p for p in paths if os.path.lexists(Path(root) / p))
