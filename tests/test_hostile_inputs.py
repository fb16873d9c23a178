"""The hostile-input campaign of issue 11 (corpus in tests/hostile.py): more than 60 generated and fixed hostile
inputs and outputs through ``gonio-reconstruct``, and hostile bench and scene files through ``gonio-capture
--check``, each as a subprocess. Every case exits 0 or 2 (1 only for an I/O fault such as a full disk) with one
line and no traceback, names the file, and leaves no output half-written under its real name."""

from __future__ import annotations

import shutil

import pytest

from tests import hostile, hostile_silent

#: every 6th case (and the full disk) as a new interpreter, ``python -m`` as a user runs it; the others as children
#: of warm interpreters (tests/forkserver.py): the same process boundary, exit status and stderr, a fraction of the
#: CPU (the corpus is about reading and refusing files; the interpreter's start was most of each run)
REAL_EVERY = 6

@pytest.fixture(scope="module")
def work(tmp_path_factory):
    d = tmp_path_factory.mktemp("hostile")
    yield d
    for p in d.rglob("*"):  # read-only and unreadable corners of the corpus
        if not p.is_symlink():
            p.chmod(0o755 if p.is_dir() else 0o644)
    shutil.rmtree(d, ignore_errors=True)


def _report(outcomes: list[hostile.Outcome]) -> str:
    return "\n".join(f"{o.case.name}: {'; '.join(o.problems)}\n    {o.stderr.strip()[-400:]}"
                     for o in outcomes if not o.clean)


@pytest.mark.slow
def test_hostile_inputs_and_outputs_of_gonio_reconstruct(work):
    cases = hostile.reconstruct_cases(work / "reconstruct")
    assert len(cases) >= 60
    outcomes = hostile.run_all(cases, real_every=REAL_EVERY)
    assert all(o.clean for o in outcomes), _report(outcomes)
    assert sum(o.code == 0 for o in outcomes) >= 8  # the valid variants (BOM, CRLF, CR, separators) do work
    full = next(o for o in outcomes if o.case.name == "output on a full disk (the table)")
    assert full.code == 1 and "disk is full" in full.stderr


@pytest.mark.slow
def test_hostile_configs_and_scenes_of_gonio_capture_check(work):
    cases = hostile.capture_check_cases(work / "capture")
    assert len(cases) >= 20
    outcomes = hostile.run_all(cases, real_every=REAL_EVERY)
    assert all(o.clean for o in outcomes), _report(outcomes)


@pytest.mark.slow
def test_issue_49_silent_wrong_answers_are_refused_or_said(work):
    """Tampered capture folders resumed (a row off the plan, a value 7000 sigma below zero, a flipped digit, the
    slice deleted or emptied under a run record, a torn line, --force), --check of a PM100 bench without a VISA
    library, and reconstructions the samples cannot support: each refused in one line naming why (the files left
    as they were) or done with the warning it needs, never a traceback, never a Python warning."""
    cases = hostile_silent.capture_cases(work / "silent-capture") + hostile_silent.reconstruct_cases(
        work / "silent-reconstruct")
    assert len(cases) >= 14
    outcomes = hostile.run_all(cases, real_every=REAL_EVERY)
    assert all(o.clean for o in outcomes), _report(outcomes)
    assert sum(o.code == 2 for o in outcomes) >= 6
