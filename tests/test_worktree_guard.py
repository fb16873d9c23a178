"""The guard of conftest.py (tests/worktree.py): files a test run leaves in the working tree are found, what a run
may write (bytecode, caches, the environment) is not."""

from __future__ import annotations

import subprocess
from pathlib import Path

import pytest

from tests import worktree


@pytest.fixture
def repo(tmp_path: Path) -> Path:
    def git(*args: str) -> None:
        subprocess.run(["git", *args], cwd=tmp_path, check=True, capture_output=True)

    git("init", "-q")
    (tmp_path / ".gitignore").write_text("out/\n__pycache__/\n")
    (tmp_path / "README.md").write_text("readme\n")
    git("add", ".")
    git("-c", "user.name=t", "-c", "user.email=t@t", "commit", "-qm", "init")
    return tmp_path


def test_files_a_run_leaves_are_found(repo):
    before = worktree.snapshot(repo)
    assert before == {}
    (repo / "out" / "run1").mkdir(parents=True)
    (repo / "out" / "run1" / "slice.csv").write_text("x\n")   # ignored by git: the snapshot leaves it to the audit
    (repo / "stray.txt").write_text("x\n")                    # untracked
    (repo / "README.md").write_text("changed\n")              # a committed file changed
    after = worktree.snapshot(repo)
    assert worktree.left_behind(before, after) == ["README.md", "stray.txt"]
    assert worktree.left_behind({}, worktree.snapshot(repo, ignored=True)) == ["README.md", "out/run1/slice.csv",
                                                                                 "stray.txt"]


AUDIT_CHILD = """
import os, sys
from pathlib import Path
sys.path.insert(0, {tests!r})
import worktree
repo, log = Path(sys.argv[1]), Path(sys.argv[2])
worktree.start_audit(repo, log)
(repo / "out" / "run2").mkdir(parents=True)
(repo / "out" / "run2" / "slice.csv").write_text("x")           # a test's own write into an ignored folder
(repo / "__pycache__").mkdir(exist_ok=True)
(repo / "__pycache__" / "m.pyc").write_bytes(b"x")              # what a run may write
open(repo / "README.md").read()                                  # a read is not a write
fd = os.open(repo / "made-by-os-open.txt", os.O_WRONLY | os.O_CREAT)
os.close(fd)
(repo / "gone.txt").write_text("x")
os.unlink(repo / "gone.txt")                                     # written and removed: not left behind
"""


def test_the_audit_sees_what_a_test_process_writes_in_ignored_folders_and_not_what_others_write(repo,
                                                                                             tmp_path_factory):
    """A user's capture into out/ while the tests run (another process) is not the tests'; a test process writing
    into out/ is."""
    import sys

    log = tmp_path_factory.mktemp("audit")  # outside the repository (the repo fixture is its own tmp_path)
    (repo / "out" / "user").mkdir(parents=True)
    before = worktree.snapshot(repo)
    (repo / "out" / "user" / "slice.csv").write_text("the user's capture\n")  # not an audited process
    code = Path(__file__).parent
    subprocess.run([sys.executable, "-c", AUDIT_CHILD.format(tests=str(code)), str(repo), str(log)], check=True)
    assert worktree.left_behind(before, worktree.snapshot(repo)) == ["made-by-os-open.txt"]
    assert worktree.audited(repo, log) == ["made-by-os-open.txt", "out/run2/slice.csv"]


def test_what_a_run_may_write_is_not_counted(repo):
    before = worktree.snapshot(repo)
    for d in ("__pycache__", ".pytest_cache", ".hypothesis", "pkg/__pycache__", "gonio_brdf.egg-info"):
        (repo / d).mkdir(parents=True, exist_ok=True)
        (repo / d / "f").write_text("x")
    (repo / ".venv").symlink_to(repo)   # the worktree's link to a shared environment
    assert worktree.left_behind(before, worktree.snapshot(repo)) == []


def test_a_file_already_there_counts_when_it_changes(repo):
    (repo / "notes.txt").write_text("mine\n")
    before = worktree.snapshot(repo)
    assert worktree.left_behind(before, worktree.snapshot(repo)) == []
    import os

    os.utime(repo / "notes.txt", ns=(1, 1))
    assert worktree.left_behind(before, worktree.snapshot(repo)) == ["notes.txt"]


def test_no_checkout_no_guard(tmp_path):
    assert worktree.snapshot(tmp_path) is None
