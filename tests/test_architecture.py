"""The house rules: import contracts (import-linter), module size, and the doctests being collected."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = ("acquisition", "reconstruction", "simulator")
#: No module of the three packages may grow beyond this many lines.
MAX_MODULE_LINES = 600


def test_import_contracts_hold():
    """`lint-imports` checks the contracts of pyproject.toml: reconstruction imports neither acquisition nor
    simulator; acquisition never imports simulator."""
    exe = Path(sys.executable).with_name("lint-imports")
    r = subprocess.run([str(exe), "--no-cache"], cwd=REPO, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stdout + r.stderr
    assert "2 kept, 0 broken" in r.stdout, r.stdout


def test_no_module_is_longer_than_600_lines():
    long = {str(p.relative_to(REPO)): n for pkg in PACKAGES for p in sorted((REPO / pkg).rglob("*.py"))
            if (n := len(p.read_text(encoding="utf-8").splitlines())) > MAX_MODULE_LINES}
    assert long == {}, f"modules over {MAX_MODULE_LINES} lines: {long}"


def test_no_unit_test_bounds_the_wall_clock():
    """Unit tests assert behaviour, not speed (a bound flakes on a loaded machine); speed is a figure that a
    benchmarks/ script prints. No test reads time.perf_counter / process_time / time.time, and none asserts an
    upper bound on a difference of time.monotonic readings. Left alone: a poll's deadline (``monotonic() <
    t_end``), which only stops a wait that would hang, and lower bounds on the simulator's real-time waits."""
    import ast

    clocks = {"perf_counter", "perf_counter_ns", "process_time", "process_time_ns", "time", "time_ns",
              "thread_time", "thread_time_ns"}

    def calls(node, names):
        for n in ast.walk(node):
            if isinstance(n, ast.Call):
                f = n.func
                name = f.attr if isinstance(f, ast.Attribute) and isinstance(f.value, ast.Name) and \
                    f.value.id == "time" else f.id if isinstance(f, ast.Name) and f.id != "time" else None
                if name in names:
                    yield n

    bad = []
    for p in sorted((REPO / "tests").glob("*.py")):
        tree = ast.parse(p.read_text(encoding="utf-8"))
        bad += [f"{p.name}:{c.lineno}: a clock read" for c in calls(tree, clocks)]
        for a in (n for n in ast.walk(tree) if isinstance(n, ast.Assert)):
            for cmp in (n for n in ast.walk(a.test) if isinstance(n, ast.Compare)):
                sides = [cmp.left, *cmp.comparators]
                elapsed = any(isinstance(s, ast.BinOp) and isinstance(s.op, ast.Sub)
                              and any(calls(s, {"monotonic", "monotonic_ns"})) for s in sides)
                if elapsed and any(isinstance(op, (ast.Lt, ast.LtE)) for op in cmp.ops):
                    bad.append(f"{p.name}:{a.lineno}: an upper bound on elapsed time")
    assert bad == [], bad


def test_every_public_function_of_geometry_and_merl_has_a_doctest_that_pytest_runs():
    import inspect

    from reconstruction import geometry, merl

    if sys.version_info >= (3, 11):
        import tomllib
    else:  # pragma: no cover
        import tomli as tomllib

    paths = tomllib.loads((REPO / "pyproject.toml").read_text())["tool"]["pytest"]["ini_options"]["testpaths"]
    assert {"reconstruction/geometry.py", "reconstruction/merl.py"} <= set(paths)
    for mod in (geometry, merl):
        funcs = [n for n in mod.__all__ if inspect.isfunction(getattr(mod, n))]
        missing = [n for n in funcs if ">>> " not in (getattr(mod, n).__doc__ or "")]
        assert funcs and missing == [], (mod.__name__, missing)
