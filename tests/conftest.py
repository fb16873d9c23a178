"""Shared, generic test fixtures: repository paths, config variants, a `gonio-sim serve` child process."""

from __future__ import annotations

import os
import shutil
import sys
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import pytest
import tomli_w

from acquisition.bench import SimulatorProcess
from tests import helpers, worktree

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

REPO = Path(__file__).resolve().parents[1]
SIMULATED_TOML = REPO / "configs" / "simulated.toml"


@pytest.fixture(scope="session")
def repo_root() -> Path:
    return REPO


@pytest.fixture(scope="session")
def simulated_toml() -> Path:
    """Path of the shared configs/simulated.toml."""
    return SIMULATED_TOML


@pytest.fixture(scope="session")
def deep_merge() -> Callable[[dict[str, Any], dict[str, Any]], dict[str, Any]]:
    """``deep_merge(base, over)`` -> a new dict with ``over`` merged into ``base`` table by table."""
    return helpers.deep_merge


def start_serve(config: Path, *extra: str, log_dir: Path) -> SimulatorProcess:
    """``gonio-sim serve --config CONFIG --log-level warning EXTRA...`` started through the capture's own
    :class:`acquisition.SimulatorProcess` (its stderr in ``log_dir``/serve-N.log, ``.log_path``)."""
    n = len(list(log_dir.glob("serve-*.log")))
    sp = SimulatorProcess(config, log_path=log_dir / f"serve-{n}.log", extra_args=("--log-level", "warning", *extra),
                          timeout_s=20.0)
    sp.start()
    return sp


@pytest.fixture(scope="session")
def serve_process(tmp_path_factory) -> Callable[..., SimulatorProcess]:
    """For module-scoped fixtures: ``serve_process(config_path, *extra_args)`` starts ``gonio-sim serve``; the
    caller stops it (``sp.stop()`` returns the exit status)."""
    log_dir = tmp_path_factory.mktemp("serve")
    return lambda config, *extra: start_serve(config, *extra, log_dir=log_dir)


@pytest.fixture(scope="session")
def base_config_dict() -> dict[str, Any]:
    """configs/simulated.toml as a dict (do not mutate; use ``config_dict``)."""
    with open(SIMULATED_TOML, "rb") as fh:
        return tomllib.load(fh)


@pytest.fixture
def config_dict(base_config_dict) -> Callable[..., dict[str, Any]]:
    """``config_dict({"simulator": {"seed": 3}})`` -> the base config deep-merged with the overrides."""

    def make(over: dict[str, Any] | None = None) -> dict[str, Any]:
        return helpers.deep_merge(base_config_dict, over or {})

    return make


@pytest.fixture
def config_file(tmp_path, config_dict) -> Callable[..., Path]:
    """Write a config variant to a TOML file in ``tmp_path`` (in the configs dir semantics: base_dir = tmp)."""
    counter = [0]

    def make(over: dict[str, Any] | None = None) -> Path:
        counter[0] += 1
        p = tmp_path / f"config{counter[0]}.toml"
        p.write_text(tomli_w.dumps(config_dict(over)))
        return p

    return make


@pytest.fixture
def serve(tmp_path) -> Iterator[Callable[..., SimulatorProcess]]:
    """Factory starting ``gonio-sim serve`` children (:func:`start_serve`); all are stopped at teardown."""
    procs: list[SimulatorProcess] = []

    def start(config: Path, *extra: str) -> SimulatorProcess:
        sp = start_serve(config, *extra, log_dir=tmp_path)
        procs.append(sp)
        return sp

    yield start
    for sp in procs:
        sp.stop()


#: the project's packages whose bytecode the session writes before any test runs
COMPILED_PACKAGES = ("reconstruction", "acquisition", "simulator", "benchmarks")


def pytest_configure(config: pytest.Config) -> None:
    """Write the bytecode of the project's packages once, in the controlling process (0.3 s), before the workers
    and the hundreds of ``python -m`` children the tests start: an editable install does not compile the project,
    and where ``PYTHONDONTWRITEBYTECODE`` is set (CI machines often do) every child would compile the modules it
    imports again (0.03-0.1 s each). Up-to-date bytecode is left as it is."""
    import compileall
    import os
    import tempfile

    if not hasattr(config, "workerinput"):  # the controller: a folder where every process says what it wrote
        os.environ[worktree.AUDIT_ENV] = tempfile.mkdtemp(prefix="gonio-test-writes-")
    if os.environ.get(worktree.AUDIT_ENV):  # the controller and each xdist worker (which inherit the variable)
        worktree.start_audit(REPO, Path(os.environ[worktree.AUDIT_ENV]))
    if hasattr(config, "workerinput"):  # a pytest-xdist worker: the controller has done it
        return
    for pkg in COMPILED_PACKAGES:
        compileall.compile_dir(REPO / pkg, quiet=1)


#: the files whose cases take longest (tens of seconds each on 2 cores), started first
LONGEST_FIRST = ("tests/test_tour.py", "tests/test_hostile_inputs.py", "tests/test_prior.py",
                 "tests/test_fault_storms.py", "tests/test_readme.py", "tests/test_study.py",
                 "tests/test_acq_integrity.py", "tests/test_htmlreport.py")


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """:data:`LONGEST_FIRST`, then the other files that hold `slow` cases, then the rest (each file's cases together
    and in their order, so its module fixtures are built once): on the two pytest-xdist workers the long cases
    start early and the quick ones fill in at the end, instead of a 30 s case starting last and running alone."""
    slow_files = {item.nodeid.split("::")[0] for item in items if item.get_closest_marker("slow")}

    def rank(item: pytest.Item) -> tuple[int, int]:
        f = item.nodeid.split("::")[0]
        return (0, LONGEST_FIRST.index(f)) if f in LONGEST_FIRST else (1 if f in slow_files else 2, 0)

    items.sort(key=rank)


# --- tests write only to temporary folders ---------------------------------------------------------------------------

_WORKTREE = pytest.StashKey[dict]()


def pytest_sessionstart(session: pytest.Session) -> None:
    """Note what the working tree holds (tests/worktree.py), in the controlling process only."""
    if not hasattr(session.config, "workerinput"):
        session.config.stash[_WORKTREE] = {"before": worktree.snapshot(REPO), "left": []}


def pytest_sessionfinish(session: pytest.Session, exitstatus: int) -> None:
    """Fail the session if its tests left files in the working tree (or changed committed ones): tests write only
    to temporary folders. Not counted: what other programs (a user's capture into ``out/``) write into git-ignored
    folders meanwhile (tests/worktree.py). Only after a whole run (a selection of tests or ``-x`` may be cut short,
    yet it is checked too: what it wrote, it wrote)."""
    state = session.config.stash.get(_WORKTREE, None)
    if state is None or state["before"] is None:
        return
    after = worktree.snapshot(REPO)
    left = set(worktree.left_behind(state["before"], after or {}))
    log_dir = os.environ.get(worktree.AUDIT_ENV)
    if log_dir:  # what the test processes themselves wrote, in ignored folders too (out/, build/)
        left.update(worktree.audited(REPO, Path(log_dir)))
        shutil.rmtree(log_dir, ignore_errors=True)
    state["left"] = sorted(left)
    if state["left"] and session.exitstatus == pytest.ExitCode.OK:
        session.exitstatus = pytest.ExitCode.TESTS_FAILED


def pytest_terminal_summary(terminalreporter: Any, exitstatus: int, config: pytest.Config) -> None:
    state = config.stash.get(_WORKTREE, None)
    if state and state["left"]:
        shown = state["left"][:20]
        more = f"\n  ... and {len(state['left']) - 20} more" if len(state["left"]) > 20 else ""
        terminalreporter.section("files left in the working tree", sep="=", red=True, bold=True)
        terminalreporter.line("the tests wrote into the repository (tests write only to temporary folders):\n  "
                              + "\n  ".join(shown) + more, red=True)
