"""The gonio-sim command line."""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]


def run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "simulator.cli", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=30)


def test_help_is_useful():
    r = run("--help")
    assert r.returncode == 0 and "serve" in r.stdout and "bench" in r.stdout
    r = run("serve", "--help")
    assert r.returncode == 0
    for opt in ("--config", "--seed", "--time-scale"):
        assert opt in r.stdout


def test_bench_help_describes_the_study():
    r = run("bench", "--help")
    assert r.returncode == 0
    for flag in ("--quick", "--scheduler", "--workers", "--materials"):
        assert flag in r.stdout


def test_bad_config_fails_cleanly(tmp_path):
    r = run("serve", "--config", str(tmp_path / "missing.toml"))
    assert r.returncode == 2 and "gonio-sim:" in r.stderr


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_serve_prints_one_json_line_and_exits_0_on_signals(serve, simulated_toml, sig):
    sp = serve(simulated_toml, "--seed", "3", "--time-scale", "0", "--log-level", "info")
    assert set(sp.ports) == {"dynamixel", "serial"}
    assert all(os.path.exists(p) for p in sp.ports.values())
    assert sp.stop(sig) == 0
    assert sp.rest_stdout == ""  # exactly one line on stdout
    assert "total simulated time" in sp.stderr
